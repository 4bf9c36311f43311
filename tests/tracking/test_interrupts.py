"""SIGTERM and Ctrl-C against a write to the tracking database.

CI once saw `kill PID` land inside MLflow's commit of a run's inputs: the interrupted transaction
kept SQLite's write lock in the process, so marking the run KILLED failed ("database is locked")
and printed a page of SQLAlchemy's traceback instead of the one `pcpg: interrupted` line. Here the
signal is sent from inside the commit itself (SQLAlchemy's commit event), so the race is hit
every time.
"""

from __future__ import annotations

import os
import signal

import pytest

from pcpg_dist.common import errors
from pcpg_dist.common.errors import Terminated, catch_sigterm, signals_held
from pcpg_dist.tracking.connection import _retry, end_quietly


@pytest.fixture
def handlers(monkeypatch):
    """catch_sigterm's handlers for the test, the process's own back after it."""
    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    signal.signal(signal.SIGINT, signal.default_int_handler)
    monkeypatch.setattr(errors, "sigterm_received", False)
    catch_sigterm()
    yield
    for s, h in before.items():
        signal.signal(s, h)


@pytest.mark.parametrize(
    ("signum", "raised"), [(signal.SIGTERM, Terminated), (signal.SIGINT, KeyboardInterrupt)]
)
def test_a_signal_inside_signals_held_is_raised_when_the_block_ends(handlers, signum, raised):
    done = []
    with pytest.raises(raised) as caught:
        with signals_held():
            with signals_held():  # nested: held until the outer block ends
                os.kill(os.getpid(), signum)
            done.append("inner")
        done.append("after")  # not reached: the signal is raised as the outer block ends
    assert done == ["inner"]
    assert (caught.type is Terminated) == (signum == signal.SIGTERM)
    with pytest.raises(raised):  # nothing held: raised at once
        os.kill(os.getpid(), signum)


def test_a_second_signal_while_one_is_held_is_raised_at_once(handlers):
    """A database that hangs (PostgreSQL behind a dropped network) must not make the command deaf:
    the second Ctrl-C stops it inside the held block."""
    done = []
    with pytest.raises(KeyboardInterrupt), signals_held():
        os.kill(os.getpid(), signal.SIGINT)
        done.append("held")
        os.kill(os.getpid(), signal.SIGINT)
        done.append("not reached")
    assert done == ["held"]
    with signals_held():  # nothing left over from the first
        done.append("clean")
    assert done == ["held", "clean"]


def test_sigterm_inside_a_store_commit_lets_it_finish_and_the_run_is_marked_killed(
    handlers, tmp_path, capfd
):
    from mlflow import MlflowClient
    from sqlalchemy import event
    from sqlalchemy.engine import Engine

    client = MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}")
    run_id = client.create_run(client.create_experiment("interrupts")).info.run_id
    sent = []

    def on_commit(conn):  # the write is flushed, the lock taken, the commit not yet made
        if not sent:
            sent.append(True)
            os.kill(os.getpid(), signal.SIGTERM)

    event.listen(Engine, "commit", on_commit)
    try:
        with pytest.raises(Terminated):
            _retry(client.log_param, run_id, "alpha", "0.5")
    finally:
        event.remove(Engine, "commit", on_commit)
    assert sent and errors.sigterm_received
    capfd.readouterr()
    end_quietly(client, run_id)  # what killed_if_interrupted and the CLI's cleanup do
    err = capfd.readouterr().err
    assert "database is locked" not in err and "Traceback" not in err, err[-2000:]
    run = client.get_run(run_id)
    assert run.info.status == "KILLED"
    assert run.data.params == {"alpha": "0.5"}  # the interrupted write was committed, not lost
