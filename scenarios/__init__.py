"""Co-simulation scenarios (one folder each); installed as ``mbdfmu.scenarios``."""
