"""The element FMUs in a non-Python FMI host: tests/c_host/fmi2_host.c, compiled here.

The FMU binary does not link libpython. The host process gets it through
LD_PRELOAD, and PYTHONHOME names the installation it belongs to. The
environment is built from nothing: no Python on PATH, no VIRTUAL_ENV, empty
PYTHONPATH, no user site. Neither webline nor pythonfmu can be imported from
site-packages there, so the FMU runs on what it bundles in resources/.
"""
import csv
import io
import os
import shutil
import subprocess
import sys
import sysconfig
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest

from fmu_loop import Instance

HOST_SRC = Path(__file__).resolve().parent / "c_host" / "fmi2_host.c"
LIBPYTHON = Path(sysconfig.get_config_var("LIBDIR") or "", sysconfig.get_config_var("LDLIBRARY") or "")
BASE_PYTHON = Path(sys.base_prefix, "bin", f"python{sys.version_info.major}.{sys.version_info.minor}")

# {21} at rest: T -> EA (v_out - v_in)/v_out + v_in T_in/v_out, time constant L0/v_out = 0.5 s
EA, L0, V_IN, V_OUT, T_IN = 2.0e4, 0.5, 1.0, 1.01, 50.0
H, N = 0.01, 1000


@pytest.fixture(scope="module")
def host(tmp_path_factory):
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("gcc not found: the C FMI host cannot be compiled")
    if not LIBPYTHON.name.endswith(".so") or not LIBPYTHON.exists():
        pytest.skip(f"this Python has no shared libpython ({LIBPYTHON}): a non-Python host cannot load the FMUs")
    exe = tmp_path_factory.mktemp("c_host") / "fmi2_host"
    p = subprocess.run([gcc, "-std=c11", "-O1", "-Wall", "-Wextra", "-Werror", "-o", str(exe), str(HOST_SRC), "-ldl"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    return exe


@pytest.fixture(scope="module")
def span(fmus, tmp_path_factory):
    """(unzip folder, model identifier, GUID, {name: value reference}) of Span.fmu."""
    unzipdir = tmp_path_factory.mktemp("span_fmu")
    with zipfile.ZipFile(fmus["Span"]) as z:
        z.extractall(unzipdir)
    root = ET.parse(unzipdir / "modelDescription.xml").getroot()
    vr = {sv.get("name"): int(sv.get("valueReference")) for sv in root.iter("ScalarVariable")}
    return unzipdir, root.find("CoSimulation").get("modelIdentifier"), root.get("guid"), vr


def foreign_env(tmp_path, preload=True):
    """Environment of a non-Python FMI tool: nothing inherited, an empty PATH folder."""
    empty = tmp_path / "bin"
    empty.mkdir(exist_ok=True)
    env = {"PATH": str(empty), "PYTHONHOME": sys.base_prefix, "PYTHONPATH": "", "PYTHONNOUSERSITE": "1"}
    if preload:
        env["LD_PRELOAD"] = str(LIBPYTHON)
    return env


def run_host(host, span, tmp_path, parameters, outputs, n=N, h=H, preload=True):
    unzipdir, model, guid, vr = span
    cmd = [str(host), str(unzipdir), model, guid, "0", repr(h), str(n)]
    for name, value in parameters.items():
        cmd += ["-s", f"{vr[name]}={value!r}"]
    for name in outputs:
        cmd += ["-o", f"{vr[name]}:{name}"]
    return subprocess.run(cmd, env=foreign_env(tmp_path, preload), cwd=tmp_path, capture_output=True, text=True,
                          timeout=60)


def test_the_environment_has_no_python_packages_to_fall_back_on(tmp_path):
    env = foreign_env(tmp_path, preload=False)
    assert shutil.which("python3", path=env["PATH"]) is None and "VIRTUAL_ENV" not in env
    # The interpreter the FMU will embed, with the same environment: neither
    # webline nor pythonfmu is importable, so the FMU must use its bundled copies.
    code = "import importlib.util as u; print([u.find_spec(m) for m in ('webline', 'pythonfmu')])"
    p = subprocess.run([str(BASE_PYTHON), "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "[None, None]"


def test_bundled_code_needs_only_the_standard_library(span, tmp_path):
    # Stricter than the host run (whose sys.path still has the base
    # interpreter's site-packages): import the FMU's module with no site at all.
    unzipdir = span[0]
    module = (unzipdir / "resources" / "slavemodule.txt").read_text().strip()
    code = (f"import sys; sys.path.insert(0, {str(unzipdir / 'resources')!r}); import {module}, webline, pythonfmu; "
            "print(webline.__file__, pythonfmu.__file__)")
    p = subprocess.run([str(BASE_PYTHON), "-I", "-S", "-c", code], env=foreign_env(tmp_path, preload=False),
                       cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    assert all(f.startswith(str(unzipdir / "resources")) for f in p.stdout.split())


def test_span_in_c_host_settles_and_matches_fmpy(host, span, fmus, tmp_path):
    params = {"EA": EA, "L0": L0, "T0": 0.0, "v_in": V_IN, "v_out": V_OUT, "T_in": T_IN}
    p = run_host(host, span, tmp_path, params, ["T", "L"])
    assert p.returncode == 0, p.stderr
    rows = list(csv.DictReader(io.StringIO(p.stdout)))
    assert len(rows) == N + 1
    t = [float(r["time"]) for r in rows]
    T = [float(r["T"]) for r in rows]
    assert T[0] == 0.0 and all(float(r["L"]) == L0 for r in rows)
    T_ss = EA * (V_OUT - V_IN) / V_OUT + V_IN * T_IN / V_OUT
    assert T_ss == pytest.approx(247.52475, rel=1e-6)
    assert T[-1] == pytest.approx(T_ss, rel=1e-7)  # 20 time constants

    # the same run through fmpy, in this process
    inst = Instance(fmus["Span"], "fmpy", {k: params[k] for k in ("EA", "L0", "T0")},
                    {k: params[k] for k in ("v_in", "v_out", "T_in")}).init()
    T_fmpy = inst.get(["T"])
    for k in range(N):
        inst.step(k * H, H)
        T_fmpy += inst.get(["T"])
    inst.free()
    assert t == pytest.approx([k * H for k in range(N + 1)], abs=1e-12)
    assert T == pytest.approx(T_fmpy, rel=1e-12, abs=1e-12)


def test_invalid_parameter_in_c_host_is_reported_by_name(host, span, tmp_path):
    p = run_host(host, span, tmp_path, {"EA": -1.0}, ["T"], n=10)
    assert p.returncode == 3, p.stderr  # a non-OK status; the host then stops calling the instance
    assert "fmi2ExitInitializationMode returned 4 (fmi2Fatal)" in p.stderr
    assert "parameter 'EA'" in p.stderr
    assert p.stdout == ""


def test_without_libpython_the_fmu_binary_does_not_load(host, span, tmp_path):
    p = run_host(host, span, tmp_path, {}, ["T"], n=1, preload=False)
    assert p.returncode == 2
    assert "undefined symbol: _Py" in p.stderr or "undefined symbol: Py" in p.stderr
