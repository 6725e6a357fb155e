"""Build every element FMU into one folder (``webline build-fmus``).

Each FMU bundles ``webline/__init__.py``, ``webline/fmi_slave.py`` and
``webline/physics/`` so it runs in a host where webline is not installed
(pythonfmu itself is bundled by its builder). A manifest holds the hash of
the sources; an up-to-date folder is not rebuilt.
"""
import functools
import hashlib
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

import webline

FMU_DIR = Path(__file__).resolve().parent
PACKAGE_DIR = Path(webline.__file__).resolve().parent


def _default_out():
    """``build/fmus`` of a source checkout; an installed webline builds into the user's cache
    (``$WEBLINE_FMU_DIR``, else ``$XDG_CACHE_HOME/webline/fmus-<version>``), never into site-packages."""
    if os.environ.get("WEBLINE_FMU_DIR"):
        return Path(os.environ["WEBLINE_FMU_DIR"])
    if (FMU_DIR.parent / "pyproject.toml").is_file():
        return FMU_DIR.parent / "build" / "fmus"
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "webline" / f"fmus-{webline.__version__}"


DEFAULT_OUT = _default_out()
MANIFEST = "manifest.json"


def scripts():
    """The FMU scripts: ``fmus/webline_*.py``, one per element type."""
    return sorted(FMU_DIR.glob("webline_*.py"))


def _bundled_sources():
    return [PACKAGE_DIR / "__init__.py", PACKAGE_DIR / "fmi_slave.py",
            *sorted((PACKAGE_DIR / "physics").glob("*.py"))]


def source_hash():
    """Hash of everything that goes into an FMU (scripts, bundled physics, pythonfmu version)."""
    import pythonfmu
    h = hashlib.sha256(pythonfmu.__version__.encode())
    for p in [*scripts(), *_bundled_sources()]:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


def model_name(script):
    """Model identifier of an FMU script: the class defined in it (one per script)."""
    st = Path(script).stat()
    # parsed once per file version: every system the fast engine builds looks the models up
    return _model_name(str(script), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=256)
def _model_name(script, mtime_ns, size):
    import ast
    tree = ast.parse(Path(script).read_text())
    names = [n.name for n in tree.body if isinstance(n, ast.ClassDef)]
    if len(names) != 1:
        raise ValueError(f"{script}: an FMU script must define exactly one class, found {names}")
    return names[0]


def fmu_paths(out=DEFAULT_OUT):
    """{model name: path of its .fmu} for the folder ``out``."""
    return {model_name(s): Path(out) / f"{model_name(s)}.fmu" for s in scripts()}


def is_current(out=DEFAULT_OUT):
    manifest = Path(out) / MANIFEST
    if not manifest.exists():
        return False
    data = json.loads(manifest.read_text())
    return data.get("hash") == source_hash() and all(p.exists() for p in fmu_paths(out).values())


def build_all(out=DEFAULT_OUT, force=False, log=print):
    """Build all FMUs into ``out``; returns {model name: path}. Skips work if up to date."""
    from pythonfmu import FmuBuilder

    out = Path(out)
    if not force and is_current(out):
        return fmu_paths(out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="webline_bundle_") as tmp:
        bundle = Path(tmp) / "webline"
        (bundle / "physics").mkdir(parents=True)
        for src in _bundled_sources():
            dst = bundle / src.relative_to(PACKAGE_DIR)
            shutil.copy2(src, dst)
        staging = Path(tmp) / "fmus"
        built = {}
        for script in scripts():
            name = model_name(script)
            log(f"building {name}.fmu")
            fmu = Path(FmuBuilder.build_FMU(script, dest=staging, project_files=[bundle]))
            # Built aside and renamed into place: a process reading the folder
            # (a parallel test or sweep worker) never sees a half-written zip.
            tmp_dst = out / f".{fmu.name}.{os.getpid()}"
            shutil.copy2(fmu, tmp_dst)
            os.replace(tmp_dst, out / fmu.name)
            built[name] = out / fmu.name
    manifest = out / f".{MANIFEST}.{os.getpid()}"
    manifest.write_text(json.dumps({"hash": source_hash(), "fmus": sorted(built)}, indent=1))
    os.replace(manifest, out / MANIFEST)
    return built


def main(argv=None):
    import argparse
    ap = argparse.ArgumentParser(prog="webline build-fmus", description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output folder (default {DEFAULT_OUT})")
    ap.add_argument("--force", action="store_true", help="rebuild even if up to date")
    args = ap.parse_args(argv)
    built = build_all(args.out, force=args.force)
    print(f"{len(built)} FMUs in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
