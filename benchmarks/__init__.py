"""The experiments beside the library: runners, harnesses and report writers (not installed)."""

# sb3_mpail first, before anything imports gymnasium (which imports its plugins): it keeps gymnasium-robotics'
# unrelated AdroitHand notice off every benchmark's output (sb3_mpail/_quiet.py)
import sb3_mpail  # noqa: F401  # isort: skip
