"""TamedPUMA: safe and stable imitation learning with geometric fabrics (Bakker et al., L4DC 2025).

Reference implementation and experiment harness. See README.md for the layout and data flow:
config -> scenario -> controller step -> simulator -> recorder -> files -> analysis.
"""

__version__ = "0.1.0"
