"""evaluation.mutation_check: every listed fault still applies to the code as it is (its text
found once) and names tests that exist; faults go into a scratch copy, never the working tree."""
import re
from pathlib import Path

import pytest

from evaluation.mutation_check import FAULTS, apply_fault, main, scratch_copy

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("fault", FAULTS, ids=lambda f: f.name)
def test_each_fault_applies_once_and_its_tests_exist(fault):
    text = (REPO / fault.path).read_text()
    assert text.count(fault.old) == 1 and fault.old != fault.new
    for test in fault.tests:
        path, _, name = test.partition("::")
        assert (REPO / path).is_file(), test
        if path.startswith("tests/") and name:
            assert re.search(rf"^def {re.escape(name)}\(", (REPO / path).read_text(), re.M), test
        elif name:      # a doctest: the function it documents
            assert f"def {name.rsplit('.', 1)[-1]}(" in (REPO / path).read_text(), test


def test_faults_go_into_the_copy(tmp_path):
    root = scratch_copy(tmp_path)
    fault = FAULTS[0]
    before = (REPO / fault.path).read_text()
    assert apply_fault(fault, root) == before
    assert fault.new in (root / fault.path).read_text()
    assert (REPO / fault.path).read_text() == before
    assert (tmp_path / "shared").resolve() == (REPO.parent / "shared").resolve()
    assert main(["--only", "no-such-fault"]) == 2
