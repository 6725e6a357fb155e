"""Mechanics of the diagnosis benchmark (diagnosis.benchmark): the derived line,
the case draw, the blind folder a diagnosis gets (truth never passed to it),
and the scorer's counts on hand-made reports. The real diagnosis is not run
here (``webline diagnose-bench --quick`` does that); a fake ``python`` records
what the subprocess would be given."""
import json
import math
import re
import stat
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from webline.diagnosis import benchmark as B


@pytest.fixture(scope="module")
def line(tmp_path_factory):
    d = tmp_path_factory.mktemp("bench_line")
    doc = B.derive_line()
    path = B.write_yaml(d / "line.yaml", doc)
    return doc, path, B.line_facts(path)


# ------------------------------------------------------------------ generator ----
def test_derived_line_is_a_valid_smaller_ewl(line):
    from webline.orchestrator.layout import load_system
    doc, path, facts = line
    assert [e["name"] for e in doc["path"]] == list(B.KEEP)
    assert "span" not in doc["path"][-1]
    assert set(doc["sensors"]) == {"lc9", "lc19"}
    assert set(doc["drives"]["speed_loops"]) == {"unwind", "sw_leader", "rewind"}
    system = load_system(path)
    assert {c.name for c in system.components} >= set(B.KEEP)
    # nothing hidden in the nominal line
    assert not any("eccentricity" in e for e in doc["path"])
    assert not any("drive" in v for v in doc["drives"]["speed_loops"].values())
    # equal radius in one zone: indistinguishable; across zones or radii: not
    assert B.indistinguishable(facts, "idler_u1") == ["idler_u1", "roller9"]
    assert B.indistinguishable(facts, "roller19") == ["idler_r1", "roller19"]
    assert B.indistinguishable(facts, "guide_in") == ["guide_in"]
    assert B.indistinguishable(facts, "sw_leader") == ["sw_leader"]
    assert B.indistinguishable(facts, "unwind") == ["unwind"]


def test_case_draw_is_deterministic_and_in_range(line):
    doc, _, facts = line
    a = B.draw_cases(36, seed=7, layout_doc=doc, facts=facts)
    b = B.draw_cases(36, seed=7, layout_doc=doc, facts=facts)
    assert [(c.category, [e.element for e in c.effects]) for c in a] == \
           [(c.category, [e.element for e in c.effects]) for c in b]
    cats = {c.category for c in a}
    assert cats == {"eccentric", "out_of_round", "noise_only", "multi", "backlash", "compliance"}
    for c in a:
        if c.category == "noise_only":
            assert c.effects == []
        if c.category == "multi":
            assert len(c.effects) >= 2
        assert not c.runs[0].holdout and c.runs[0].unwind_radius_in == 6.375
        for e in c.effects:
            if e.kind in B.PERIODIC:
                assert facts[e.element]["kind"] == e.kind
                assert 1 <= len(e.C_m) <= 6
                assert 0.05e-3 <= max(e.C_m) <= 1.0e-3 + 1e-12
                assert all(x == 0 or 0.05e-3 <= x <= max(e.C_m) for x in e.C_m)
            else:
                assert facts[e.element]["driven"]
                assert (e.drive["backlash"] > 0) == (e.kind == "backlash")
        for r in c.runs:
            if c.category in B.DRIVE_KINDS:
                assert r.profile != "constant"  # a drive effect needs a torque change to show
    assert any(r.holdout for c in a for r in c.runs)
    assert any(len([r for r in c.runs if not r.holdout]) > 1 for c in a)
    q = B.draw_cases(3, seed=0, quick=True, layout_doc=doc, facts=facts)
    assert [c.category for c in q] == ["eccentric", "noise_only", "out_of_round"]
    assert all(len(c.runs) == 1 and c.runs[0].duration_s <= 4 for c in q)


FAKE = """#!{python}
import json, os, sys
from pathlib import Path
args = sys.argv[1:]
out = Path(args[args.index("--out") + 1])
out.mkdir(parents=True, exist_ok=True)
files = sorted(str(p) for p in Path.cwd().rglob("*"))
(out / "seen.json").write_text(json.dumps({{"argv": args, "cwd": os.getcwd(), "files": files}}))
(out / "report.json").write_text({report})
"""


def test_blind_case_and_subprocess_never_see_the_truth(line, tmp_path, fmus):
    doc, _, facts = line
    case = B.Case("c01", "eccentric", [B.Effect("eccentricity", "idler_u1", C_m=[0.4e-3, 0.0, 0.1e-3],
                                                psi_rad=[0.5, 0.0, -1.0])],
                  [B.RunSpec("run1", speed_fpm=200.0, duration_s=3.0, noise_N=0.05, lbf=True,
                             extra=["line_speed", "unwind.pulse"], seed=1),
                   B.RunSpec("run2", speed_fpm=160.0, unwind_radius_in=5.5, duration_s=3.0, holdout=True,
                             noise_N=0.05, seed=2)])
    truth = B.make_case(case, tmp_path / "c01", doc, fmus)
    blind = tmp_path / "c01" / "blind"
    assert sorted(p.name for p in blind.iterdir()) == ["line.yaml", "run1.csv", "run1.yaml", "run2.csv", "run2.yaml"]
    assert (tmp_path / "c01" / "truth" / "truth.json").exists()
    # the nominal layout is the derived line, unchanged
    assert yaml.safe_load((blind / "line.yaml").read_text()) == doc
    # run files: data + experiment conditions only
    for name in ("run1", "run2"):
        spec = yaml.safe_load((blind / f"{name}.yaml").read_text())
        assert set(spec) == {"data", "experiment"}
        assert set(spec["experiment"]) <= {"duration", "line_speed", "roll_radius", "tension"}
    head = (blind / "run1.csv").read_text().splitlines()[0].split(",")
    assert head == ["time [s]", "lc19 [lbf]", "lc9 [lbf]", "line_speed [ft/min]", "unwind.pulse"]
    assert (blind / "run2.csv").read_text().splitlines()[0].split(",") == ["time [s]", "lc19 [N]", "lc9 [N]"]
    text = "".join(p.read_text() for p in blind.glob("*.yaml"))
    assert "eccentricity" not in text and "truth" not in text and "idler_u1:" not in text
    # the effect is in the data: lc9 oscillates at the roller's frequency beyond the noise
    t = np.loadtxt(blind / "run1.csv", delimiter=",", skiprows=1)
    assert np.std(t[len(t) // 3:, 2]) * B.LBF > 3 * 0.05
    f = truth["runs"][0]["fundamental_hz"]["idler_u1"]
    assert abs(f - 200 * B.FPM / (2 * math.pi * 1.5 * B.INCH)) / f < 0.02
    assert truth["effects"][0]["indistinguishable"] == ["idler_u1", "roller9"]
    assert set(truth["runs"][0]["drive_torque"]) == {"unwind", "sw_leader", "rewind"}
    assert truth["runs"][0]["drive_torque"]["unwind"]["max_Nm"] < 0  # an unwind holds back: no reversal

    # the diagnosis subprocess: only the blind folder, the holdout run flagged
    report = {"effects": [{"element": "roller9", "kind": "eccentricity", "fundamental_hz": f,
                           "candidates": [{"element": "roller9"}, {"element": "idler_u1"}],
                           "harmonics": [{"order": 1, "amplitude": 0.4e-3, "phase": 0.5}]}],
              "holdout": {"in_sample": {"lc9.T": {"nominal": {"nrmse": 1.0, "rms": 2.0},
                                                  "refined": {"nrmse": 0.1, "rms": 0.1}}},
                          "out_of_sample": {"lc9.T": {"nominal": {"nrmse": 1.0, "rms": 2.0},
                                                      "refined": {"nrmse": 0.3, "rms": 0.5}}}}}
    fake = tmp_path / "fake_python"
    fake.write_text(FAKE.format(python=sys.executable, report=repr(json.dumps(report))))
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    d = B.run_diagnosis(truth, tmp_path / "c01" / "diagnosis", python=str(fake))
    assert d["returncode"] == 0, d["stderr"]
    seen = json.loads((tmp_path / "c01" / "diagnosis" / "seen.json").read_text())
    assert Path(seen["cwd"]) == blind.resolve()
    assert seen["argv"][:4] == ["-m", "webline.cli", "diagnose", "line.yaml"]
    assert seen["argv"][4] == "run1.yaml"
    assert seen["argv"][seen["argv"].index("--holdout") + 1:] == ["run2.yaml"]
    assert not any("truth" in a for a in seen["argv"])
    assert not any("truth" in p for p in seen["files"])
    sc = B.score_case(truth, d["report"])
    assert [m["mode"] for m in sc["matches"]] == ["ambiguous"]
    g = B.gap_of(d["report"], truth)
    assert g["held_out"]["ratio"] == pytest.approx(0.3)
    assert 0 < g["held_out"]["oracle_ratio"] < 1


# -------------------------------------------------------------------- scorer ----
def _truth(effects, cat="eccentric", runs=None):
    facts_ind = {"idler_u1": ["idler_u1", "roller9"], "roller9": ["idler_u1", "roller9"],
                 "guide_in": ["guide_in"], "unwind": ["unwind"], "sw_leader": ["sw_leader"]}
    out = []
    for el, kind in effects:
        e = {"element": el, "kind": kind, "indistinguishable": facts_ind.get(el, [el])}
        if kind in B.PERIODIC:
            e.update(C_m=[1e-4, 5e-4], psi_rad=[0.0, 1.0], dominant_order=2)
        out.append(e)
    runs = runs or [{"name": "run1", "holdout": False,
                     "fundamental_hz": {"idler_u1": 5.0, "roller9": 5.0, "guide_in": 6.8, "unwind": 1.0,
                                        "sw_leader": 1.05},
                     "sensors": {"lc9": {"noise_rms_N": 0.05, "std_measured_N": 1.0, "n": 1000}}}]
    return {"id": "x", "category": cat, "effects": out, "runs": runs}


def _eff(el, kind, cands=None, f=None, harm=None):
    return {"element": el, "kind": kind, "candidates": [{"element": c} for c in (cands or [el])],
            "fundamental_hz": f, "harmonics": harm or []}


def test_scorer_counts_on_hand_made_reports():
    # exact match, with frequency and dominant-harmonic errors
    t = _truth([("unwind", "out_of_round")], "out_of_round")
    sc = B.score_case(t, {"effects": [_eff("unwind", "out_of_round", f=1.01,
                                           harm=[{"order": 2, "amplitude": 4e-4, "phase": 1.1}])]})
    (m,) = sc["matches"]
    assert m["mode"] == "exact" and sc["false"] == [] and sc["missed"] == []
    assert m["f_rel_error"] == pytest.approx(0.01)
    assert m["amp_rel_error"] == pytest.approx(0.2)
    assert m["phase_error_rad"] == pytest.approx(0.1)

    # indistinguishable (equal radius, one zone) and listed: ambiguous match
    t = _truth([("idler_u1", "eccentricity")])
    sc = B.score_case(t, {"effects": [_eff("roller9", "eccentricity", ["roller9", "idler_u1"], f=5.0)]})
    assert [m["mode"] for m in sc["matches"]] == ["ambiguous"]
    # ... but not listed among the candidates: no match
    sc = B.score_case(t, {"effects": [_eff("roller9", "eccentricity", ["roller9"], f=5.0)]})
    assert sc["matches"] == [] and len(sc["false"]) == 1 and len(sc["missed"]) == 1
    # ... or a candidate the report's own pattern excludes (not in its tie): no match
    sc = B.score_case(t, {"effects": [dict(_eff("roller9", "eccentricity", ["roller9", "idler_u1"], f=5.0),
                                           tie=["roller9"])]})
    assert sc["matches"] == [] and len(sc["false"]) == 1 and len(sc["missed"]) == 1
    # listed, but physically distinguishable (another radius): no match
    t2 = _truth([("guide_in", "eccentricity")])
    sc = B.score_case(t2, {"effects": [_eff("roller9", "eccentricity", ["roller9", "guide_in"], f=5.0)]})
    assert sc["matches"] == [] and len(sc["false"]) == 1 and len(sc["missed"]) == 1
    # right element, wrong kind
    t3 = _truth([("sw_leader", "backlash")], "backlash")
    sc = B.score_case(t3, {"effects": [_eff("sw_leader", "compliance")]})
    assert sc["matches"] == [] and sc["false"][0]["kind"] == "compliance" and sc["missed"][0]["kind"] == "backlash"
    # two truths, one report listing both: one match only (one to one); exact preferred
    t4 = _truth([("idler_u1", "eccentricity"), ("roller9", "eccentricity")], "multi")
    sc = B.score_case(t4, {"effects": [_eff("idler_u1", "eccentricity", ["idler_u1", "roller9"], f=5.0)]})
    assert [(m["mode"], m["element"]) for m in sc["matches"]] == [("exact", "idler_u1")]
    assert sc["missed"] == [{"element": "roller9", "kind": "eccentricity"}]
    # backlash is only detectable where the drive torque reverses in a fit run
    tq = _truth([("sw_leader", "backlash")], "backlash")
    tq["runs"][0]["drive_torque"] = {"sw_leader": {"min_Nm": -2.0, "max_Nm": 0.05}}
    assert B.torque_reverses(tq, "sw_leader") is True
    tq["runs"][0]["drive_torque"] = {"sw_leader": {"min_Nm": 0.02, "max_Nm": 0.05}}
    assert B.torque_reverses(tq, "sw_leader") is False
    assert B.torque_reverses(tq, "unwind") is None
    # a shaft: found on its element; the torsional mode's error reported, not a condition of the match
    tc = _truth([("rewind", "compliance")], "compliance")
    tc["effects"][0]["drive"] = {"torsional_hz": 10.0}
    (m,) = B.score_case(tc, {"effects": [dict(_eff("rewind", "compliance"), fundamental_hz=8.4)]})["matches"]
    assert m["torsional_rel_error"] == pytest.approx(0.16) and m["torsional_true_hz"] == 10.0
    # noise only: every reported effect is false
    t5 = _truth([], "noise_only")
    sc5 = B.score_case(t5, {"effects": [_eff("guide_in", "eccentricity", f=6.8)]})
    assert sc5["n_true"] == 0 and len(sc5["false"]) == 1
    # a failed diagnosis (no report): all missed
    sc6 = B.score_case(t, None)
    assert sc6["missed"] and not sc6["false"]


def test_summary_precision_recall_and_targets():
    T = B.PERIODIC
    runs = [{"name": "run1", "holdout": False, "fundamental_hz": {"idler_u1": 5.0, "roller9": 5.0, "guide_in": 6.8,
                                                                  "unwind": 1.0},
             "sensors": {"lc9": {"noise_rms_N": 0.05, "std_measured_N": 1.0, "n": 1000}}},
            {"name": "run2", "holdout": True, "fundamental_hz": {"idler_u1": 4.0, "roller9": 4.0, "guide_in": 5.4,
                                                                 "unwind": 0.9},
             "sensors": {"lc9": {"noise_rms_N": 0.05, "std_measured_N": 0.5, "n": 1000}}}]

    def gap(n_in, r_in, n_out, r_out):
        return {"in_sample": {"lc9.T": {"nominal": {"nrmse": n_in, "rms": 1.0}, "refined": {"nrmse": r_in, "rms": .1}}},
                "out_of_sample": {"lc9.T": {"nominal": {"nrmse": n_out, "rms": 1.0},
                                            "refined": {"nrmse": r_out, "rms": .1}}}}

    cases = [  # (truth effects, reported effects, gap)
        ([("idler_u1", "eccentricity")], [_eff("idler_u1", "eccentricity", f=5.05)], gap(1, .1, 1, .2)),
        ([("idler_u1", "eccentricity")], [_eff("roller9", "eccentricity", ["roller9", "idler_u1"], f=5.0)],
         gap(1, .1, 1, .6)),
        ([("guide_in", "eccentricity")], [], gap(1, 1, 1, 1)),
        ([("unwind", "out_of_round")], [_eff("unwind", "out_of_round", f=1.0),
                                        _eff("guide_in", "eccentricity", f=6.8)], gap(1, .2, 1, .3)),
        ([], [_eff("guide_in", "eccentricity", f=6.8)], gap(1, 1, 1, 1)),
        ([], [], gap(1, 1, 1, 1)),
    ]
    results = []
    for i, (te, re_, g) in enumerate(cases):
        tr = _truth(te, "x", runs)
        tr["id"] = f"c{i}"
        rep = {"effects": re_, "holdout": g}
        results.append({"truth": tr, "report": rep, "score": B.score_case(tr, rep), "gap": B.gap_of(rep, tr),
                        "wall_s": 10.0 + i})
    s = B.summarize(results)
    ecc = s["per_kind"]["eccentricity"]
    # eccentricity: 3 true, 2 matched (1 exact, 1 ambiguous), 4 reported (2 false: case 3 and noise case)
    assert (ecc["true"], ecc["matched"], ecc["exact"], ecc["ambiguous"], ecc["reported"]) == (3, 2, 1, 1, 4)
    assert ecc["precision"] == pytest.approx(0.5) and ecc["recall"] == pytest.approx(2 / 3)
    oor = s["per_kind"]["out_of_round"]
    assert (oor["precision"], oor["recall"]) == (1.0, 1.0)
    assert s["periodic"]["matched"] == 3 and s["periodic"]["reported"] == 5 and s["periodic"]["true"] == 4
    assert s["noise_only"] == {"cases": 2, "false_effects": 1, "cases_with_false": 1}
    assert s["verdict"]["no_invented_effect"] == "fail"
    assert s["verdict"]["eccentricity_recall"] == "fail" and s["verdict"]["out_of_round_precision"] == "pass"
    assert s["fundamental_rel_error"]["n"] == 3
    assert s["fundamental_rel_error"]["max"] == pytest.approx(0.01)
    h = s["gap"]["held_out_halved_periodic"]
    assert h == {"cases": 4, "halved": 2}
    assert s["gap"]["held_out_ratio_periodic"]["median"] == pytest.approx(0.45)
    assert s["verdict"]["held_out_gap_halved"].startswith("fail")
    assert s["runtime_s"]["max"] == 15.0
    md = B.markdown(s, results, {"seed": 0, "jobs": 2, "wall_s": 60, "cpus": 2})
    assert "| eccentricity: precision | 50 % (2/4) (of which 1 ambiguous) |" in md
    assert "| invented effects on noise-only cases | 1 in 2 cases | 0 | fail |" in md
    assert len(re.findall(r"\n\| c\d ", md)) == len(cases)


# ------------------------------------------------------------------ time limit ----
STOPPABLE = '''#!{python}
import json, signal, sys, time
from pathlib import Path
out = Path(sys.argv[sys.argv.index("--out") + 1])
out.mkdir(parents=True, exist_ok=True)
def term(signum, frame):
    raise KeyboardInterrupt("terminated by SIGTERM")
signal.signal(signal.SIGTERM, signal.SIG_IGN if {ignore} else term)
try:
    (out / "report_partial.json").write_text(json.dumps({{"stopped": {{"stage": "refine"}},
                                                          "stages_done": ["runs", "nominal"]}}))
    time.sleep(60)
except KeyboardInterrupt:
    sys.exit(130)
'''


@pytest.mark.parametrize("ignores_interrupt", [False, True])
def test_a_diagnosis_over_its_time_is_terminated_then_killed(tmp_path, monkeypatch, ignores_interrupt):
    # at the limit the diagnosis gets SIGTERM (it then writes what it had measured, as on
    # Ctrl-C: diagnose_cmd), and SIGKILL only if it has not stopped within the grace period
    blind = tmp_path / "blind"
    blind.mkdir()
    for name in ("line.yaml", "run1.yaml"):
        (blind / name).write_text("{}\n")
    fake = tmp_path / "fake_python"
    fake.write_text(STOPPABLE.format(python=sys.executable, ignore=ignores_interrupt))
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setattr(B, "TIMEOUT_GRACE", 1.0)
    truth = {"blind_folder": str(blind), "runs": [{"name": "run1", "holdout": False}]}
    d = B.run_diagnosis(truth, tmp_path / "diagnosis", timeout=2.0, python=str(fake))
    assert d["returncode"] == -9 and d["report"] is None
    assert d["stderr"].startswith("timeout after 2 s")
    assert d["partial"]["stage"] == "refine" and d["partial"]["stages_done"] == ["runs", "nominal"]
    # terminated: it stops at once; ignoring the signal: killed after the grace period
    assert d["wall_s"] < 2.0 + (1.0 if ignores_interrupt else 0.0) + 20.0
    assert d["wall_s"] >= 2.0 + (1.0 if ignores_interrupt else 0.0)
