"""webline: roll-to-roll web line models from primitive-element FMUs.

Kept free of imports: ``webline.physics`` is bundled into every FMU and must
load without the rest of the package (or numpy) being importable.
"""

__version__ = "0.1.0"
