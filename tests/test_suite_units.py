"""The test suite's own work units (tests/conftest.py): the xdist scheduler, which sees test ids only, must
send every test that uses the end-to-end run to the one worker that builds it."""

from conftest import E2E_FIXTURE, requesting_tests


def test_the_scheduler_finds_exactly_the_tests_that_use_the_end_to_end_run(request):
    """Checked on what this session collected (selected or deselected by -m / -k, as far as pytest kept them)."""
    items = request.session.items
    selected = {it.nodeid.split("[")[0] for it in items}
    using = {it.nodeid.split("[")[0] for it in items if E2E_FIXTURE in it.fixturenames}
    found = requesting_tests(E2E_FIXTURE)
    assert using <= found, using - found
    assert found & selected == using, (found & selected) - using
    assert "tests/test_kill_resume.py::test_killed_runs_resume_to_the_uninterrupted_result" in found
