"""The driver's ask/tell loop: ``parallel_trials`` Ray tasks in flight, Optuna told each result as
it arrives. A task that raises is told FAIL with its error in the trial's user attributes, and
the study goes on; a trial that draws the parameters of one in flight shares its task, one that
draws those of a finished trial reuses its result (trials are deterministic)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from pcpg_dist.config.stages import TuneConfig
from pcpg_dist.orchestration.tuning.space import suggest
from pcpg_dist.orchestration.tuning.storage import Storage, fail_stale, finished_count


class TrialPool:
    """The trials in flight on Ray for one study, and what the driver owes them (heartbeats,
    stale checks, a FAIL when it stops)."""

    def __init__(
        self,
        study: Any,
        storage: Storage,
        tune: TuneConfig,
        start_trial: Callable[[dict[str, int]], Any],
    ) -> None:
        self.study, self.storage, self.tune = study, storage, tune
        self.start_trial = start_trial  # params -> the ObjectRef of its Ray task
        # ObjectRef -> the trials waiting on it
        self.in_flight: dict[Any, list[Any]] = {}
        self.by_params: dict[tuple, Any] = {}
        self.last_check = time.monotonic()
        self.stale: list[int] = []

    def waiting(self) -> list[Any]:
        """Every trial asked and not told yet."""
        return [t for ts in self.in_flight.values() for t in ts]

    def fill(self, advance: Callable[[], None]) -> None:
        """Ask trials until ``parallel_trials`` tasks run or ``n_trials`` are finished or asked."""
        study, tune = self.study, self.tune
        while (
            len(self.in_flight) < tune.parallel_trials
            and finished_count(study) + sum(map(len, self.in_flight.values())) < tune.n_trials
        ):
            trial = study.ask()
            if self.storage.heartbeat:
                self.storage.storage.record_heartbeat(trial._trial_id)
            params = suggest(trial, tune)
            trial.set_user_attr("params_full", params)
            key = tuple(sorted(params.items()))
            if key in self.by_params:
                self.in_flight[self.by_params[key]].append(trial)
            elif _reuse(study, trial, key):
                advance()
            else:
                ref = self.start_trial(params)
                self.in_flight[ref], self.by_params[key] = [trial], ref

    def wait(self) -> list[Any]:
        """The next finished task (none when a heartbeat is due first); heartbeats and stale
        checks for the trials still waiting."""
        import ray

        done, _ = ray.wait(
            list(self.in_flight),
            num_returns=1,
            timeout=self.tune.heartbeat_interval if self.storage.heartbeat else None,
        )
        waiting = self.waiting()
        if self.storage.heartbeat:
            for t in waiting:
                self.storage.storage.record_heartbeat(t._trial_id)
            if time.monotonic() - self.last_check > self.tune.heartbeat_interval:
                self.stale += fail_stale(
                    self.study, self.storage, self.tune, mine={t._trial_id for t in waiting}
                )
                self.last_check = time.monotonic()
        return done

    def tell_done(self, ref: Any, advance: Callable[[], None]) -> None:
        """Tell Optuna the result of one finished task, for every trial waiting on it."""
        self.by_params = {k: r for k, r in self.by_params.items() if r != ref}
        for trial in self.in_flight.pop(ref):
            _tell(self.study, trial, ref)
            advance()

    def fail_in_flight(self) -> None:
        """The driver stops: fail every trial in flight now, so a resumed study reruns it."""
        from optuna.storages import RetryHeartbeatStaleTrialCallback
        from optuna.trial import TrialState

        retry = RetryHeartbeatStaleTrialCallback(max_retry=self.tune.max_retry)
        for trial in self.waiting():  # interrupted: fail now, rerun on resume
            trial.set_user_attr("error", "interrupted: the driver stopped")
            self.study.tell(trial, state=TrialState.FAIL)
            retry(self.study, self.study._storage.get_trial(trial._trial_id))


def _reuse(study: Any, trial: Any, key: tuple) -> bool:
    """Tell ``trial`` the outcome of a finished trial with the same parameters, if there is one."""
    from optuna.trial import TrialState

    for old in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)):
        if tuple(sorted(old.user_attrs.get("params_full", {}).items())) == key:
            for k, v in old.user_attrs.items():
                trial.set_user_attr(k, v)
            trial.set_user_attr("duplicate_of", old.number)
            if old.state == TrialState.COMPLETE:
                study.tell(trial, old.value)
            else:
                study.tell(trial, state=TrialState.PRUNED)
            return True
    return False


def _error_text(exc: BaseException) -> str:
    """One line naming the trial's own exception (not Ray's wrapper)."""
    cause = getattr(exc, "cause", None) or exc
    text = (
        f"{type(cause).__name__}: {cause}".splitlines()[0] if str(cause) else type(cause).__name__
    )
    return text[:500]


def _tell(study: Any, trial: Any, ref: Any) -> None:
    """Report one finished Ray task to Optuna: COMPLETE, PRUNED (with reason) or FAIL (with error)."""
    import ray
    from optuna.trial import TrialState

    try:
        res = ray.get(ref)
    except Exception as e:  # noqa: BLE001 - any trial error: record it, the study goes on
        trial.set_user_attr("error", _error_text(e))
        study.tell(trial, state=TrialState.FAIL)
        return
    for k, v in res["metrics"].items():
        if isinstance(v, float) and math.isfinite(v):
            trial.set_user_attr(k, v)
    if res["pruned"]:
        trial.set_user_attr("pruned_reason", res["pruned"])
        study.tell(trial, state=TrialState.PRUNED)
    else:
        study.tell(trial, res["value"])
