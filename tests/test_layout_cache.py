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
