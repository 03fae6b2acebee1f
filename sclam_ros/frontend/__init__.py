"""The front end: LaserScan → points → KISS-ICP + point-to-line refinement → z_ij, encoder
conditioning and scan synchronisation, keyframes. May import: core."""
