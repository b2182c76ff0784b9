"""Multi-view capture: rig files, frame synchronisation and rig calibration (seed 000 sec. 4,
seed 002 sec. 3)."""
