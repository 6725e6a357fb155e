"""Every scenario file validates and builds a well-formed System that matches the FMUs' variables;
the schema and docs stay in step with the models."""
import json
import math
from pathlib import Path

import pytest
import yaml

from webline.orchestrator.layout import build_system, json_schema, load_layout, load_system

ROOT = Path(__file__).resolve().parents[1]


def _is_layout(path):
    """Layout files (not sweep files, which name a ``layout`` to run)."""
    data = yaml.safe_load(path.read_text())
    return isinstance(data, dict) and "layout" not in data


SCENARIOS = sorted(p for p in (ROOT / "scenarios").rglob("*.yaml") if _is_layout(p))
PAPER = ROOT / "scenarios" / "paper"


def fmu_variables():
    """{model: (parameters, inputs, outputs)} from the FMU scripts' declarations."""
    from webline.orchestrator.reference import fmu_classes
    out = {}
    for model, cls in fmu_classes().items():
        out[model] = ({v.name for v in cls.parameters()}, {v.name for v in cls.INPUTS}, {v.name for v in cls.OUTPUTS})
    return out


def test_scenarios_exist():
    names = {p.relative_to(ROOT / "scenarios").as_posix() for p in SCENARIOS}
    assert {"ewl.yaml", "ewl_out_of_round.yaml"} <= names
    for prefix in ("a_", "b_", "c_", "d_", "e_", "f_"):
        assert any(n.startswith("paper/" + prefix) for n in names), prefix
    assert sum(n.startswith("paper/c_") for n in names) == 3
    assert sum(n.startswith("paper/d_") for n in names) == 3
    assert sum(n.startswith("paper/e_") for n in names) == 2


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.relative_to(ROOT / "scenarios").as_posix())
def test_scenario_builds_a_consistent_system(path):
    system = load_system(path)
    assert system.check() == []
    assert 0 < system.experiment.stop - system.experiment.start <= 30.0
    assert system.experiment.step == pytest.approx(2e-3)  # docs/performance.md: error < 0.5 % on the EWL
    json.dumps(system.meta)  # recorded with the results: must serialise
    variables = fmu_variables()
    models = {c.name: c.model for c in system.components}
    for c in system.components:
        params, inputs, _ = variables[c.model]
        assert set(c.parameters) <= params, (c.name, set(c.parameters) - params)
        assert set(c.inputs) <= inputs, (c.name, set(c.inputs) - inputs)
        assert all(math.isfinite(v) for v in (*c.parameters.values(), *c.inputs.values())), c.name
    for k in system.connections:
        assert k.src_var in variables[models[k.src]][2], k
        assert k.dst_var in variables[models[k.dst]][1], k
    fed = {(k.dst, k.dst_var) for k in system.connections}
    for c in system.components:  # every input a model reads is fed or has its start value
        if c.model in ("IdleRoller", "DrivenRoller", "UnwindRoll", "RewindRoll"):
            need = {"T_in", "T_out", "tau"} & variables[c.model][1]
            assert all((c.name, n) in fed for n in need), c.name


def test_ewl_structure():
    s = load_system(ROOT / "scenarios" / "ewl.yaml")
    count = {}
    for c in s.components:
        count[c.model] = count.get(c.model, 0) + 1
    assert count == {"UnwindRoll": 1, "RewindRoll": 1, "IdleRoller": 9, "DrivenRoller": 3, "Span": 13,
                     "SpeedPI": 5, "TensionPI": 2, "LoadCell": 3, "Profile": 7}
    m = s.meta
    assert m["master"] == "sw_leader" and m["layout"].endswith("ewl.yaml")
    assert {k: m["elements"][k]["radius"] for k in ("unwind", "idler_u1", "guide_in", "sw_leader")} == \
        pytest.approx({"unwind": 6.375 * 0.0254, "idler_u1": 1.5 * 0.0254, "guide_in": 1.1 * 0.0254,
                       "sw_leader": 6.05 * 0.0254})
    assert len(m["rotating"]) == 14 and m["rotating"][0]["radius_output"] == "R"
    assert m["units"]["display"]["speed"]["unit"] == "ft/min"
    assert m["units"]["display"]["tension"]["si_per_unit"] == pytest.approx(4.4482216152605)
    assert "ft/min" in m["units"]["written"] and "lbf" in m["units"]["written"]
    zones = [z for z in m["zones"] if z["tension_loop"]]
    assert [(z["up"], z["down"], z["load_cell"]) for z in zones] == [("unwind", "sw_leader", "lc9"),
                                                                     ("pull_roll", "rewind", "lc19")]
    pis = {c.name: c for c in s.components if c.model == "SpeedPI"}
    assert {n: c.parameters["K_ref"] for n, c in pis.items()} == {
        "unwind_speed_pi": 15, "sw_leader_speed_pi": 20, "sw_follower_speed_pi": 20,
        "pull_roll_speed_pi": 40, "rewind_speed_pi": 15}
    assert all(c.parameters["zeta"] == 1.1 for c in pis.values())
    u, r = s.component("unwind_zone_tension_pi"), s.component("rewind_zone_tension_pi")
    ft_min_per_lbf = 0.3048 / 60 / 4.4482216152605
    assert u.parameters["K"] == pytest.approx(2 * ft_min_per_lbf) and u.parameters["sign"] == -1
    assert r.parameters["K"] == pytest.approx(3 * ft_min_per_lbf) and r.parameters["sign"] == 1
    assert u.parameters["w_i"] == r.parameters["w_i"] == 10
    assert s.component("line_speed").parameters["y[1]"] == pytest.approx(1.016)
    assert s.component("unwind_zone_T_ref").parameters["y[1]"] == pytest.approx(15 * 4.4482216152605)


def test_out_of_round_unwind_feeds_the_first_span():
    s = load_system(ROOT / "scenarios" / "ewl_out_of_round.yaml")
    span1 = s.component("span1").parameters
    assert [span1[f"up.C[{j}]"] for j in range(1, 7)] == pytest.approx([0.6e-3, 0.9e-3, 0.25e-3, 0.3e-3,
                                                                         0.1e-3, 0.12e-3])
    assert span1["up.C[7]"] == span1["up.C[8]"] == 0.0
    assert span1["up.psi[2]"] == pytest.approx(math.radians(40))
    assert "down.C[1]" not in span1  # the idler downstream is round
    feeds = {(k.src, k.src_var) for k in s.connections if k.dst == "span1"}
    assert {("unwind", "theta"), ("unwind", "omega")} <= feeds
    assert s.experiment.stop == 20.0


@pytest.mark.parametrize("speed", [100, 200, 300])
def test_paper_c_speeds(speed):
    s = load_system(PAPER / f"c_out_of_round_{speed}fpm.yaml")
    assert s.component("line_speed").parameters["y[1]"] == pytest.approx(speed * 0.00508)
    unwind = s.meta["elements"]["unwind"]
    # {30}-{31} from first principles: f = omega/(2 pi), the unwind turning with the unstretched web
    assert unwind["f0"] == pytest.approx(speed * 0.00508 / (2 * math.pi * 6.375 * 0.0254), rel=0.02)


@pytest.mark.parametrize("radius", ["6_75", "5_75", "4_75"])
def test_paper_d_radii(radius):
    s = load_system(PAPER / f"d_unwind_radius_{radius}in.yaml")
    R = float(radius.replace("_", ".")) * 0.0254
    assert s.component("unwind").parameters["R0"] == pytest.approx(R)
    assert s.meta["elements"]["unwind"]["radius"] == pytest.approx(R)
    eccentric = {n for n, e in s.meta["elements"].items() if e["eccentric"]}
    assert {"unwind", "sw_leader", "guide_in", "guide_out", "idler_u1"} <= eccentric


def test_paper_e_alternative_paths():
    no_guide = load_system(PAPER / "e_path_without_web_guide.yaml")
    names = {c.name for c in no_guide.components}
    assert not {"guide_in", "guide_out"} & names
    span = next(s for s in no_guide.meta["spans"] if s["up"] == "idler_u1")
    assert span["down"] == "idler_u2" and span["length"] == pytest.approx(1.9)
    no_swrap = load_system(PAPER / "e_path_without_s_wrap.yaml")
    assert no_swrap.meta["master"] == "pull_roll"
    assert not {"sw_leader", "sw_follower", "sw_leader_speed_pi"} & {c.name for c in no_swrap.components}
    zone = next(z for z in no_swrap.meta["zones"] if z["tension_loop"] == "unwind_zone")
    assert (zone["up"], zone["down"]) == ("unwind", "pull_roll")


def test_paper_a_and_f_profiles():
    a = load_system(PAPER / "a_tension_step_zero_speed.yaml")
    p = a.component("unwind_zone_T_ref").parameters
    lbf = 4.4482216152605
    assert [p[f"t[{k}]"] for k in (1, 2, 3)] == [0.0, 2.0, 2.0]
    assert [p[f"y[{k}]"] for k in (1, 2, 3)] == pytest.approx([5 * lbf, 5 * lbf, 25 * lbf])
    assert all(e["omega0"] == 0 for e in a.meta["elements"].values())
    f = load_system(PAPER / "f_accel_decel.yaml")
    p = f.component("line_speed").parameters
    n = int(p["n"])
    ts = [p[f"t[{k}]"] for k in range(1, n + 1)]
    ys = [p[f"y[{k}]"] / 0.00508 for k in range(1, n + 1)]
    assert ts == pytest.approx([0, 2, 12, 17, 25]) and ys == pytest.approx([0, 0, 300, 300, 50])
    # the other driven elements follow the same profile scaled by their speed ratio (1 at rest)
    q = f.component("unwind_v_ref").parameters
    assert [q[f"t[{k}]"] for k in range(1, n + 1)] == ts


def test_committed_schema_is_current():
    committed = json.loads((ROOT / "docs" / "layout.schema.json").read_text())
    assert committed == json_schema(), "regenerate: webline validate --schema > docs/layout.schema.json"


def test_schema_accepts_a_layout_file_and_rejects_unknown_keys():
    import jsonschema
    schema = json.loads((ROOT / "docs" / "layout.schema.json").read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    validator = jsonschema.Draft202012Validator(schema)
    data = yaml.safe_load((ROOT / "scenarios" / "ewl.yaml").read_text())
    assert list(validator.iter_errors(data)) == []
    data["experiment"]["algoritm"] = "jacobi"
    assert list(validator.iter_errors(data))


def test_docs_example_is_a_valid_layout(tmp_path):
    text = (ROOT / "docs" / "layout.md").read_text()
    example = text.split("```yaml\n", 1)[1].split("```", 1)[0]
    p = tmp_path / "demo.yaml"
    p.write_text(example)
    s = build_system(load_layout(p))
    assert s.check() == [] and s.meta["master"] == "pull"
