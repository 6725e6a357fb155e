"""Bad layouts: every problem reported as ``file:line: field: reason`` before anything runs."""
import pytest

from webline.orchestrator.layout import LayoutError, load_layout, load_system
from webline.orchestrator.validate_cmd import main as validate_main

# A small valid line; the tests edit one line and expect that line in the error.
MINI = """\
name: mini
web:
  width: 6 in
  thickness: 0.19 mm
  EA: 5800 N
  density: 390 kg/m^3
path:
  - name: unwind
    type: unwind
    radius: 6 in
    core_radius: 1.75 in
    core_inertia: 0.05 kg*m^2
    span: 1 m
  - name: lc_roller
    type: load_cell_roller
    radius: 1.5 in
    inertia: 1e-3 kg*m^2
    span: 1 m
  - name: pull
    type: driven_roller
    radius: 3 in
    inertia: 0.05 kg*m^2
    span: 1 m
  - name: idler
    type: idle_roller
    radius: 1.5 in
    mass: 0.5 kg
    span: 1 m
  - name: rewind
    type: rewind
    radius: 3 in
    core_radius: 1.75 in
    core_inertia: 0.05 kg*m^2
drives:
  master: pull
  speed_loops:
    unwind: {K_ref: 15 1/s}
    pull: {K_ref: 40 1/s}
    rewind: {K_ref: 15 1/s}
  tension_loops:
    uz: {element: unwind, load_cell: lc, K: 2 (ft/min)/lbf}
sensors:
  lc: {roller: lc_roller}
experiment:
  duration: 2 s
  line_speed: 200 ft/min
  tension: {uz: 1.5 PLI}
"""
LINES = MINI.splitlines()


def line_of(text, nth=1):
    """1-based number of the nth line of MINI that contains ``text``."""
    hits = [i + 1 for i, s in enumerate(LINES) if text in s]
    return hits[nth - 1]


def write(tmp_path, text, name="line.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def edit(old, new, nth=1):
    i = line_of(old, nth) - 1
    lines = list(LINES)
    if new is None:
        del lines[i]
    else:
        lines[i] = lines[i].replace(old, new)
    return "\n".join(lines) + "\n"


def error_of(path, overrides=None):
    with pytest.raises(LayoutError) as e:
        load_system(path, overrides)
    return e.value


def test_mini_is_valid(tmp_path):
    system = load_system(write(tmp_path, MINI))
    assert system.check() == []


def test_unknown_key_names_file_line_field_and_suggests(tmp_path):
    p = write(tmp_path, edit("    radius: 6 in", "    radius: 6 in\n    colour: red"))
    err = error_of(p)
    assert str(err).startswith(f"{p}:{line_of('radius: 6 in') + 1}: path.unwind.colour: unknown key")
    assert "core_radius" in str(err)  # the allowed keys are listed
    p = write(tmp_path, edit("    mass: 0.5 kg", "    mass: 0.5 kg\n    fricton: 0"))
    assert "path.idler.fricton: unknown key; did you mean 'friction'?" in str(error_of(p))


def test_missing_field_points_at_its_parent(tmp_path):
    p = write(tmp_path, edit("    core_radius: 1.75 in", None))  # the unwind's
    assert str(error_of(p)) == f"{p}:{line_of('- name: unwind')}: path.unwind.core_radius: required field missing"
    p = write(tmp_path, edit("  duration: 2 s", None))
    assert str(error_of(p)) == f"{p}:{line_of('experiment:')}: experiment.duration: required field missing"


def test_wrong_dimension(tmp_path):
    p = write(tmp_path, edit("line_speed: 200 ft/min", "line_speed: 200 kg"))
    msg = str(error_of(p))
    assert msg.startswith(f"{p}:{line_of('line_speed')}: experiment.line_speed: expected a speed")
    assert "'200 kg'" in msg


def test_radius_below_core(tmp_path):
    p = write(tmp_path, edit("radius: 6 in", "radius: 1.5 in"))
    msg = str(error_of(p))
    assert msg.startswith(f"{p}:{line_of('radius: 6 in')}: path.unwind.radius: roll radius 0.0381 m must be above "
                          f"the core radius")


def test_unknown_element_is_named_with_a_suggestion(tmp_path):
    p = write(tmp_path, edit("master: pull", "master: pul"))
    msg = str(error_of(p))
    assert msg.startswith(f"{p}:{line_of('master: pull')}: drives.master: unknown element 'pul'; did you mean 'pull'?")
    p = write(tmp_path, edit("lc: {roller: lc_roller}", "lc: {roller: lc_rolr}"))
    assert f"{p}:{line_of('lc: {roller')}: sensors.lc.roller: unknown roller 'lc_rolr'" in str(error_of(p))


@pytest.mark.parametrize("old, new, field, reason, at", [
    # ``at``: (text of MINI whose line the error names, lines after it)
    ("    span: 1 m", "    span: 0 m", "path.unwind.span", "must be > 0", ("    span: 1 m", 0)),
    ("thickness: 0.19 mm", "thickness: -0.19 mm", "web.thickness", "must be > 0", ("thickness", 0)),
    ("radius: 3 in", "radius: 0 in", "path.pull.radius", "must be > 0", ("radius: 3 in", 0)),
    ("K: 2 (ft/min)/lbf", "K: 2", "drives.tension_loops.uz.K", "needs an explicit unit", ("uz: {", 0)),
    ("type: idle_roller", "type: roller", "path.idler.type", "unknown element type 'roller'",
     ("type: idle_roller", 0)),
    ("mass: 0.5 kg", "mass: 0.5 kg\n    inertia: 1e-3 kg*m^2", "path.idler", "exactly one of inertia and mass",
     ("- name: idler", 0)),
    ("EA: 5800 N", "EA: 5800 N\n  E: 200 MPa", "web", "exactly one of E", ("web:", 0)),
    ("tension: {uz: 1.5 PLI}", "tension: {uz: 2000 lbf}", "experiment.tension.uz", "below the web's EA",
     ("tension: {uz", 0)),
    ("tension: {uz: 1.5 PLI}", "tension: {}", "experiment.tension", "no reference for tension loop 'uz'",
     ("tension: {uz", 0)),
    ("lc: {roller: lc_roller}", "lc: {roller: idler}", "sensors.lc.roller", "not a load_cell_roller",
     ("lc: {roller", 0)),
    ("    pull: {K_ref: 40 1/s}", "    idler: {K_ref: 40 1/s}", "drives.speed_loops.idler", "is a idle_roller",
     ("    pull: {K_ref", 0)),
    ("duration: 2 s", "duration: 2 s\n  algorithm: rk4", "experiment.algorithm",
     "must be 'jacobi' or 'gauss-seidel'", ("duration: 2 s", 1)),
    ("    mass: 0.5 kg", "    mass: 0.5 kg\n    inner_radius: 2 in", "path.idler.inner_radius", "must be below",
     ("    mass: 0.5 kg", 1)),
])
def test_field_errors(tmp_path, old, new, field, reason, at):
    p = write(tmp_path, edit(old, new))
    msg = str(error_of(p))
    line = line_of(at[0]) + at[1]
    assert any(s.startswith(f"{p}:{line}: {field}: ") and reason in s for s in msg.splitlines()), msg


def test_tension_zone_must_be_bounded_by_driven_elements(tmp_path):
    # the rewind's loop reads a load cell on the other side of the pull roll
    text = edit("    uz: {element: unwind, load_cell: lc, K: 2 (ft/min)/lbf}",
                "    uz: {element: unwind, load_cell: lc, K: 2 (ft/min)/lbf}\n"
                "    rz: {element: rewind, load_cell: lc, K: 3 (ft/min)/lbf}")
    text = text.replace("tension: {uz: 1.5 PLI}", "tension: {uz: 1.5 PLI, rz: 10 lbf}")
    p = write(tmp_path, text)
    msg = str(error_of(p))
    assert f"{p}:{line_of('uz: {element') + 1}: drives.tension_loops.rz.load_cell: tension zone not bounded by " \
           f"driven elements" in msg
    assert "pull" in msg


def test_every_problem_is_reported_sorted_by_line(tmp_path):
    text = edit("radius: 6 in", "radius: 6 kg").replace("line_speed: 200 ft/min", "line_speed: fast")
    err = error_of(write(tmp_path, text))
    assert len(err.issues) == 2
    assert [i.field for i in err.issues] == ["path.unwind.radius", "experiment.line_speed"]


def test_override_errors_name_the_override(tmp_path):
    p = write(tmp_path, MINI)
    msg = str(error_of(p, {"unwind.radius": "1 in"}))
    assert msg.startswith(f"{p}: --set unwind.radius=1 in: path.unwind.radius: roll radius")
    msg = str(error_of(p, {"path.nosuch.radius": "1 in"}))
    assert "--set path.nosuch.radius=1 in: path.nosuch: no item 'nosuch'" in msg


def test_overrides_apply_before_validation(tmp_path):
    p = write(tmp_path, MINI)
    layout = load_layout(p, {"unwind.radius": "5 in", "experiment.line_speed": "100 fpm",
                             "path.pull.span.length": "2 m", "experiment.tension.uz": 20})
    assert layout.path[0].radius == pytest.approx(0.127)
    assert layout.experiment.line_speed == pytest.approx(0.508)
    assert layout.path[2].span.length == 2.0
    assert layout.experiment.tension["uz"] == 20.0
    layout = load_layout(p, {"path.idler": "null", "path.pull.span": "2 m"})  # delete an element
    assert [e.name for e in layout.path] == ["unwind", "lc_roller", "pull", "rewind"]


def test_yaml_problems(tmp_path):
    p = write(tmp_path, MINI.replace("  thickness: 0.19 mm\n", "  thickness: 0.19 mm\n  width: 7 in\n"))
    assert str(error_of(p)) == f"{p}:{line_of('thickness') + 1}: web.width: duplicate key (first given on line 3)"
    p = write(tmp_path, "web: [1, 2\npath: 3\n")
    assert str(error_of(p)).startswith(f"{p}:2: YAML syntax:")
    assert str(error_of(tmp_path / "none.yaml")).startswith(f"{tmp_path / 'none.yaml'}: cannot read the layout")


def test_errors_in_a_base_file_name_the_base(tmp_path):
    write(tmp_path, edit("radius: 6 in", "radius: 6 kg"), "base.yaml")
    p = write(tmp_path, "base: base.yaml\nexperiment:\n  duration: -3 s\n", "derived.yaml")
    lines = str(error_of(p)).splitlines()
    assert f"{tmp_path / 'base.yaml'}:{line_of('radius: 6 in')}: path.unwind.radius: expected a length" in lines[0]
    assert lines[1].startswith(f"{p}:3: experiment.duration: must be > 0")


def test_base_merge_and_set_block(tmp_path):
    write(tmp_path, MINI, "base.yaml")
    p = write(tmp_path, "base: base.yaml\n"
                        "set:\n"
                        "  path.idler: null\n"
                        "  path.pull.span: 1.5 m\n"
                        "  unwind.eccentricity: {C: [1 mm]}\n"
                        "experiment:\n"
                        "  duration: 5 s\n"
                        "sensors:\n"
                        "  lc: {filter: 5 ms}\n", "derived.yaml")
    layout = load_layout(p)
    assert [e.name for e in layout.path] == ["unwind", "lc_roller", "pull", "rewind"]
    assert layout.experiment.duration == 5.0 and layout.experiment.line_speed == pytest.approx(1.016)
    assert layout.sensors["lc"].roller == "lc_roller" and layout.sensors["lc"].filter == 0.005
    assert layout.path[0].eccentricity.C == [0.001]


def test_validate_command(tmp_path, capsys):
    good = write(tmp_path, MINI)
    assert validate_main([str(good)]) == 0
    assert "ok" in capsys.readouterr().out
    assert validate_main([str(good), "--show"]) == 0
    assert "operating point" in capsys.readouterr().out
    assert validate_main([str(good), "--set", "experiment.line_speed=200 kg"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{good}: --set experiment.line_speed=200 kg: experiment.line_speed: expected a speed")
    bad = write(tmp_path, edit("master: pull", "master: pul"), "bad.yaml")
    assert validate_main([str(bad)]) == 2
    assert capsys.readouterr().err.startswith(f"{bad}:{line_of('master: pull')}: drives.master: unknown element")
    assert validate_main([str(good), "--set", "novalue"]) == 2
    assert validate_main([]) == 2


def test_webline_cli_dispatches_validate(tmp_path, capsys):
    from webline.cli import COMMANDS, main
    assert COMMANDS["validate"][0] == "webline.orchestrator.validate_cmd"
    assert main(["validate", str(write(tmp_path, MINI))]) == 0


def test_rewind_may_start_on_its_bare_core(tmp_path):
    p = write(tmp_path, MINI)
    s = load_system(p, {"rewind.radius": "1.75 in"})
    assert s.component("rewind").parameters["R0"] == s.component("rewind").parameters["R_core"]
    msg = str(error_of(p, {"rewind.radius": "1.75 in", "rewind.core_inertia": 0}))
    assert "path.rewind.core_inertia: must be > 0 for a rewind starting on its bare core" in msg
    assert "path.unwind.radius: roll radius" in str(error_of(p, {"unwind.radius": "1.75 in"}))


def test_layout_made_in_code_is_checked_when_built():
    import yaml
    from webline.orchestrator.layout import Layout, build_system
    data = yaml.safe_load(MINI)
    system = build_system(Layout.model_validate(data, context={"width": 0.1524}))
    assert system.check() == [] and system.meta["layout"] == "<layout>"
    data["drives"]["master"] = "nobody"
    with pytest.raises(LayoutError, match=r"^<layout>: drives.master: unknown element 'nobody'"):
        build_system(Layout.model_validate(data, context={"width": 0.1524}))
