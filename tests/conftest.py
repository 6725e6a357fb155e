"""Shared fixtures: the element FMUs, built once per test session."""
import pytest


@pytest.fixture(scope="session")
def fmus():
    """{model name: path of its .fmu}, built (or reused if up to date) by ``fmus.build.build_all``."""
    from webline.fmus.build import build_all
    return build_all(log=lambda *a: None)


# Files of whole diagnoses, each minutes on one core: collected first, so that the workers
# (`make test` runs one a core, a file each) start on them and end on short files.
FIRST = ("test_diagnose_same_frequency.py", "test_diagnose_coherence_weights.py", "test_diagnose_combined_forms.py",
         "test_diagnose_claims.py", "test_diagnose_roll_radius.py", "test_diagnose_compliance.py",
         "test_diagnose_phantom.py", "test_diagnose.py", "test_diagnose_backlash.py", "test_diagnose_confirm.py",
         "test_diagnose_regress.py")


def pytest_collection_modifyitems(session, config, items):
    def rank(item):
        name = item.path.name
        if item.get_closest_marker("slow"):
            return 0
        return 1 + FIRST.index(name) if name in FIRST else len(FIRST) + 1
    items.sort(key=rank)  # stable: a file's tests keep their order


# pythonfmu instances live inside the test process (fmpy, libcosim). On rare
# runs the interpreter's own teardown after the last test aborted with
# "corrupted double-linked list" (glibc, exit 134) although every test had
# passed: C++ slave objects holding Python references are destroyed after
# Python has begun finalising. The outcome is known once the session ends,
# so report it and leave without the teardown (see webline.cli for the same).
_EXIT = {}


def pytest_sessionfinish(session, exitstatus):
    _EXIT["status"] = int(exitstatus)


def pytest_unconfigure(config):
    if "status" in _EXIT:
        from webline.cli import exit_now
        exit_now(_EXIT["status"])
