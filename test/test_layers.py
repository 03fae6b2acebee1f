"""The package's layers import only downwards (docs/architecture.md), checked on the source.

Every import statement of every module is read with ``ast`` (including imports inside
functions, which a runtime check of ``sys.modules`` would miss), and its target is mapped
to a layer of sclam_ros or to one of the third-party families only one layer may use.
"""
import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "sclam_ros"

# layer → the sclam_ros layers it may import (besides itself)
ALLOWED = {
    "core": set(),
    "frontend": {"core"},
    "online": {"core", "frontend"},
    "diagnosis": {"core", "frontend"},
    "io": {"core", "frontend", "online", "diagnosis"},
    "sim": {"core", "io"},
    "fleet": {"core", "frontend", "online", "diagnosis", "io"},
    "ros": {"core", "frontend", "online", "diagnosis", "io", "sim"},
    "cli": {"core", "frontend", "online", "diagnosis", "io", "sim", "ros", "fleet"},
}
# third-party families → the only layers that may import them
RESTRICTED = {
    "rclpy": {"ros"}, "rosgraph_msgs": {"ros"}, "sensor_msgs": {"ros"}, "nav_msgs": {"ros"},
    "std_msgs": {"ros"}, "geometry_msgs": {"ros"}, "diagnostic_msgs": {"ros"},
    "std_srvs": {"ros"}, "rcl_interfaces": {"ros"}, "tf2_msgs": {"ros"},
    "rosbags": {"io"}, "yourdfpy": {"io"},
    "dask": {"fleet"}, "distributed": {"fleet"},
}


def imports_of(path: Path, package: Path = PACKAGE):
    """(line, dotted target) of every import in a module, relative imports resolved."""
    tree = ast.parse(path.read_text(), str(path))
    module_parts = list(path.relative_to(package.parent).with_suffix("").parts)
    if module_parts[-1] == "__init__":
        module_parts = module_parts[:-1]
        package_parts = module_parts
    else:
        package_parts = module_parts[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package_parts[: len(package_parts) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            if target == "sclam_ros":  # from sclam_ros import core, ...
                for alias in node.names:
                    yield node.lineno, f"sclam_ros.{alias.name}"
            else:
                yield node.lineno, target


def layer_of(path: Path, package: Path = PACKAGE):
    parts = path.relative_to(package).parts
    return parts[0] if len(parts) > 1 else None  # None: sclam_ros/__init__.py


def violations(package: Path = PACKAGE):
    found = []
    for path in sorted(package.rglob("*.py")):
        layer = layer_of(path, package)
        if layer is None:
            continue
        for line, target in imports_of(path, package):
            where = f"{path.relative_to(package.parent)}:{line} imports {target}"
            top = target.split(".")
            if top[0] == "sclam_ros":
                if len(top) < 2 or top[1] == layer:
                    continue
                if top[1] not in ALLOWED[layer]:
                    found.append(f"{where}: layer {layer} may not import layer {top[1]}")
            elif top[0] in RESTRICTED and layer not in RESTRICTED[top[0]]:
                found.append(f"{where}: only {sorted(RESTRICTED[top[0]])} may import {top[0]}")
    return found


def test_every_module_belongs_to_a_known_layer():
    layers = {layer_of(p) for p in PACKAGE.rglob("*.py")} - {None}
    assert layers == set(ALLOWED), f"layers without rules (or rules without layers): {layers ^ set(ALLOWED)}"


def test_layers_import_only_downwards():
    assert violations() == []


@pytest.mark.parametrize("layer, statement", [
    ("core", "import rclpy"),
    ("core", "from sclam_ros.frontend import sync"),
    ("frontend", "from sclam_ros.cli import main"),
    ("online", "from sensor_msgs.msg import LaserScan"),
    ("diagnosis", "from ...ros import node"),
    ("core", "from rosbags.highlevel import AnyReader"),
])
def test_a_forbidden_import_is_caught(tmp_path, layer, statement):
    """The check fails when a module imports against the direction (the check can fail)."""
    package = tmp_path / "sclam_ros"
    for name in ALLOWED:
        (package / name).mkdir(parents=True)
        (package / name / "__init__.py").write_text("")
    (package / layer / "bad.py").write_text(
        "def late():\n    " + statement.replace("...", "..") + "\n")
    found = violations(package)
    assert len(found) == 1 and "bad.py:2" in found[0], found
