"""A layout file is parsed once per version: the copy handed out is the file's
current content, and what a caller changes in it never reaches the next caller."""
import os

from webline.orchestrator import layout_source as LS


def test_parsed_once_per_version_and_copied(tmp_path):
    f = tmp_path / "line.yaml"
    f.write_text("name: a\nweb: {width: 6 in}\n")
    first = LS.load_yaml(f)
    first["name"] = "changed by a caller"
    first.pop("web")
    again = LS.load_yaml(f)
    assert again["name"] == "a" and "web" in again
    # a new version of the file (other content, later modification time) is read again
    f.write_text("name: bb\nweb: {width: 8 in}\n")
    st = f.stat()
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 10_000_000))
    assert LS.load_yaml(f)["name"] == "bb"


def _same(a, b, where="<root>"):
    """Equal located data: values, key order, and every key's and item's file:line."""
    assert type(a) is type(b), where
    if isinstance(a, dict):
        assert list(a) == list(b) and a.loc == b.loc and a.key_locs == b.key_locs, where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert a.loc == b.loc and a.item_locs == b.item_locs, where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    else:
        assert a == b, where


def test_the_fast_parser_reads_as_the_pure_one(tmp_path):
    """libyaml (where PyYAML has it) gives the same data at the same lines, merge keys and
    a set block included; a file that does not parse gets the pure parser's message."""
    from pathlib import Path

    import pytest
    import yaml

    from webline.orchestrator.layout import LayoutError
    scenarios = sorted((Path(__file__).parent.parent / "scenarios").glob("*.yaml"))
    f = tmp_path / "variant.yaml"
    f.write_text("base: ewl.yaml\nd: &d {a: 1 in, b: [1, 2.5, 'x']}\ne:\n  <<: *d\n  c: null\n"
                 "set:\n  path.unwind.radius: 6 in\n  drives.speed_loops.unwind.feedforward: none\n")
    for p in [*scenarios, f]:
        text = p.read_text()
        _same(LS._load_yaml_text(p, text, yaml.SafeLoader), LS._load_yaml_text(p, text))
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: a\n  web: [1, 2\n")
    with pytest.raises(LayoutError) as fast:
        LS._load_yaml_text(bad, None)
    with pytest.raises(LayoutError) as pure:
        LS._load_yaml_text(bad, None, yaml.SafeLoader)
    assert str(fast.value) == str(pure.value) and ":2: YAML syntax:" in str(fast.value)
