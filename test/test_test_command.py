"""The test command (`hand-suite test`): the pytest-xdist workers it asks for, and a ROS domain
of its own for every worker."""

from __future__ import annotations

import pytest
from ros_helpers import session_domain

from hand_control.cli import TEST_WORKERS_MAX, parse_args, xdist_options


@pytest.mark.parametrize(("cpus", "workers"), [(2, 2), (3, 3), (64, TEST_WORKERS_MAX)])
def test_one_worker_per_cpu_tests_handed_out_one_by_one(cpus: int, workers: int) -> None:
    assert xdist_options(["test/test_x.py"], cpus) == ["-n", str(workers), "--dist", "load"]


@pytest.mark.parametrize("cpus", [None, 1])
def test_one_cpu_runs_the_tests_in_one_process(cpus: int | None) -> None:
    assert xdist_options([], cpus) == []


@pytest.mark.parametrize("args", [["-n", "3"], ["-n3"], ["--numprocesses=0"],
                                  ["-p", "no:xdist"], ["-x", "-n", "0", "test/test_x.py"]])
def test_workers_chosen_on_the_command_line_are_kept(args: list[str]) -> None:
    assert xdist_options(args, 2) == []


def test_every_worker_gets_a_domain_of_its_own() -> None:
    base = {"ROS_DOMAIN_ID": "37"}
    assert session_domain(base, 1) == "37"  # the controller keeps the session's
    domains = [session_domain({**base, "PYTEST_XDIST_WORKER": f"gw{k}"}, 1) for k in range(4)]
    assert domains == ["38", "39", "40", "41"]
    assert session_domain({"ROS_DOMAIN_ID": "100", "PYTEST_XDIST_WORKER": "gw0"}, 1) == "1"
    drawn = session_domain({}, 12345)  # none set: drawn from the pid, in 1..100
    assert drawn == session_domain({}, 12345) and 1 <= int(drawn) <= 100


@pytest.mark.parametrize(("argv", "passed"), [
    (["test"], []),
    (["test", "-n", "0"], ["-n", "0"]),
    (["test", "--durations=30", "test/test_sim.py"], ["--durations=30", "test/test_sim.py"]),
    (["test", "test/test_sim.py", "-x"], ["test/test_sim.py", "-x"]),
    (["test", "-x", "test/test_sim.py", "-k", "not slow"],
     ["-x", "test/test_sim.py", "-k", "not slow"]),
])
def test_the_test_command_hands_every_argument_to_pytest(argv, passed) -> None:
    assert parse_args(argv).pytest_args == passed


def test_other_commands_refuse_arguments_they_do_not_know(capsys) -> None:
    assert parse_args(["train", "touch", "--quick"]).train_args == ["--quick"]
    with pytest.raises(SystemExit):
        parse_args(["bench", "sim", "--bogus"])
    assert "unrecognized arguments: --bogus" in capsys.readouterr().err
