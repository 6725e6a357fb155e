"""bench/first_looks.py: the table of every seed's blind first look is read from the
result files, row by row, and its summary counts the targets met from those rows."""
import importlib.util
import json
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _module():
    spec = importlib.util.spec_from_file_location("first_looks", os.path.join(ROOT, "bench", "first_looks.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _write(folder, seed, precision, recall, worse, amp_ok, amp_n):
    fam = {"meta": {"seed": seed, "wall_s": 600.0 * seed, "code": {"commit": f"c{seed}"}},
           "target_scores": {"cases": 24, "precision": precision, "recall": recall,
                             "detectable": {"recall_detectable": min(1.0, recall + 0.05)},
                             "worse_cases": [{"id": f"c0{i}"} for i in range(worse)],
                             "closed_share_in_sample": {"median": 0.97}, "closed_share_held_out": {"median": 0.9},
                             "amplitude": {"ok": amp_ok, "n": amp_n, "flagged": 2},
                             "noise_only": {"invented_periodic": 0}},
           "cases": [{"cpu_s": 60.0, "simulations": {"count": 100}}] * 3}
    with open(os.path.join(folder, f"diagnosis_results_seed{seed}_first.json"), "w") as fh:
        json.dump({"families": {"independent": fam}}, fh)


def test_each_first_look_is_a_row_and_the_summary_counts_the_targets_met(tmp_path):
    fl = _module()
    _write(tmp_path, 10, 0.95, 0.80, 0, 18, 19)
    _write(tmp_path, 9, 0.85, 0.92, 2, 17, 17)
    (tmp_path / "diagnosis_results_seed9.json").write_text("{}")   # not a first look: ignored
    rs = fl.rows(str(tmp_path))
    assert [r["seed"] for r in rs] == [9, 10]
    assert rs[0]["worse"] == 2 and rs[0]["commit"] == "c9" and rs[1]["cpu_min"] == 3.0 and rs[1]["sims"] == 300
    text = fl.table(rs)
    assert "| 9 | c9 | 85 % | 92 % (97 %) | 2 of 24 |" in text, text
    assert "| 10 | c10 | 95 % | 80 % (85 %) | 0 of 24 | 0.97 / 0.90 | 18/19 (2) | 0 | 100.0 / 3.0 | 300 |" in text, text
    assert ("precision >= 90 % 1, recall >= 90 % 1, no sensor worse 1, every run-out amplitude within 20 % "
            "or flagged 1, nothing invented on noise 2") in text, text


def test_the_committed_first_looks_read():
    """Every first look kept in bench/ reads (a file the script cannot read fails here)."""
    fl = _module()
    rs = fl.rows()
    assert rs and all(r["cases"] == 24 and 0.0 <= r["precision"] <= 1.0 for r in rs)


def test_by_kind_counts_finds_detectable_and_false_claims(tmp_path):
    fl = _module()

    def eff(el, kind, det):
        return {"element": el, "kind": kind, "detectable": {"detectable": det}}

    cases = [{"truth": {"effects": [eff("idler_u1", "eccentricity", True), eff("sw_leader", "compliance", True)]},
              "score": {"matches": [{"element": "idler_u1", "kind": "eccentricity"}],
                        "false": [{"element": "unwind", "kind": "compliance"}]}},
             {"truth": {"effects": [eff("rewind", "backlash", False)]}, "score": {"matches": [], "false": []}},
             {"truth": {"effects": []}, "score": {}}]
    for seed in (3, 12):
        fam = {"meta": {"seed": seed}, "target_scores": {}, "cases": cases}
        with open(tmp_path / f"diagnosis_results_seed{seed}_first.json", "w") as fh:
            json.dump({"families": {"independent": fam}}, fh)
    seeds, count = fl.by_kind(str(tmp_path))
    assert seeds == [3, 12]
    assert count["eccentricity"] == dict(hidden=2, detectable=2, found=2, found_detectable=2, false=0)
    assert count["compliance"] == dict(hidden=2, detectable=2, found=0, found_detectable=0, false=2)
    assert count["backlash"] == dict(hidden=2, detectable=0, found=0, found_detectable=0, false=0)
    assert fl.by_kind(str(tmp_path), last=1)[0] == [12]                    # seeds in numeric order, not text
    text = fl.kind_table(str(tmp_path))
    assert "| compliance | 2 | 0 (0 %) | 2 | 0 (0 %) | 2 |" in text and "| backlash | 2 | 0 (0 %) | 0 | 0 (-) | 0 |" in text
