"""The test suite's own work units (tests/conftest.py): the xdist scheduler, which sees test ids only, must
send every test that uses the end-to-end run to the one worker that builds it."""

from conftest import E2E_FIXTURE, tests_using


def test_the_scheduler_finds_exactly_the_tests_that_use_the_end_to_end_run(request):
    items = request.session.items
    modules = {it.nodeid.split("::")[0] for it in items}
    using = {it.nodeid.split("[")[0] for it in items if E2E_FIXTURE in it.fixturenames}
    found = {t for t in tests_using(E2E_FIXTURE) if t.split("::")[0] in modules}
    assert found == using
    assert "tests/test_kill_resume.py::test_killed_runs_resume_to_the_uninterrupted_result" in tests_using(E2E_FIXTURE)
