"""TamedPUMA: safe and stable imitation learning with geometric fabrics (Bakker et al., L4DC 2025).

Reference implementation and experiment harness. The layout and data flow (docs/extending.md):
config -> scenario -> controller step -> simulator -> recorder -> files -> analysis.
"""

__version__ = "0.1.0"
