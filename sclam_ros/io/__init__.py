"""Input and output: rosbag2 via rosbags (the only rosbags importer), message conversion by duck
typing, converters of published logs, figures. May import: core, frontend, online, diagnosis."""
