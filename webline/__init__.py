"""webline: roll-to-roll web line models from primitive-element FMUs.

Kept free of third-party imports: ``webline.physics`` is bundled into every
FMU and must load without the rest of the package (or numpy) being importable.

The design card's folders ``orchestrator/``, ``diagnosis/`` and ``fmus/`` are
the subpackages ``webline.orchestrator``, ``webline.diagnosis`` and
``webline.fmus``: an installed webline holds them inside this package
(pyproject's package-dir); in a source checkout they sit beside it, and the
checkout's root joins ``__path__`` so that the checkout being run, not some
other copy, supplies them.
"""
import os as _os

__version__ = "0.1.0"

_root = _os.path.dirname(_os.path.dirname(_os.path.abspath(__file__)))
if _os.path.isfile(_os.path.join(_root, "pyproject.toml")) and _os.path.isdir(_os.path.join(_root, "orchestrator")):
    __path__.append(_root)
