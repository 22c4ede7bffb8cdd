"""The online learner's core (the learner node only wires it): on the schedule or on demand it
snapshots the cell's bag and starts ``thermal-comp learn`` on it in a process of its own, from
the twin in use and against the prior in use (the type's twin and the node's ``prior_path``;
after an adoption the adopted unit's twin, prior and configuration), so learn's open-loop test is
against the twin the running prior was built on and its adaptive test against the running prior
(``--current-prior``/``--current-config``; talc_model.online.learn_job), polls it without ever waiting, and when it ends reads learn's own
adoption decision (talc_model.online.learn_report). A prior learn adopted is offered to the model
node (the ``AdoptPrior`` service), which checks, warms and swaps it (talc_model.online.prior_swap);
everything else (learn failed, timed out, not adopted, the offer refused) is one audit line and
the running model goes on. No rclpy.
"""
from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass, field

from talc_model.online.audit import append_audit, audit_record
from talc_model.online.learn_job import JobEnd, JobState, LearnJob, learn_argv, snapshot_bag, start_job
from talc_model.online.learn_report import ReportError, read_decision
from talc_model.online.prior_swap import prior_digest
from talc_model.online.schedule import LearnSchedule

#: the cell-relative names of the services (the model node serves adopt_prior, the learner learn_now)
SERVICE_ADOPT_PRIOR = "adopt_prior"
SERVICE_LEARN_NOW = "learn_now"


@dataclass
class LearnerConfig:
    recording: str                  # the recorder's bag folder (or .mcap file)
    twin: str                       # the type's twin learn starts from (preset or YAML file)
    work_dir: str                   # one sub-folder per learning (snapshot, learn's output, its logs)
    every_h: float = 0.0            # model hours between learnings; 0 = on demand only
    timeout_s: float = 600.0        # wall-clock limit of one learn subprocess
    train_fraction: float = 0.8     # learn's --train-h as a fraction of the hours recorded so far
    command: list[str] = field(default_factory=list)
    audit_path: str = ""
    prior_path: str = ""            # the prior the model starts from (the audit's old digest; learn's test)
    config_path: str = ""           # the configuration it runs with ('' = learn's default for its twin)

    def __post_init__(self):
        if not (0.05 < self.train_fraction <= 0.95):
            raise ValueError(f"train_fraction: {self.train_fraction!r} must be in (0.05, 0.95] "
                             "(learn keeps 5-80 % of the recording held out)")
        if not (math.isfinite(self.timeout_s) and self.timeout_s > 0):
            raise ValueError(f"learn_timeout_s: {self.timeout_s!r} must be a number of seconds > 0")
        if not self.command:
            raise ValueError("learn_command: empty")


@dataclass
class Offer:
    """A prior learn adopted, to offer to the model node."""

    prior_path: str
    config_path: str
    report_path: str
    sha256: str
    figures: dict
    unit_twin: str = ""


class OnlineLearner:
    """See the module docstring; ``poll`` is called from a timer, ``observe`` with model time."""

    def __init__(self, cfg: LearnerConfig):
        self.cfg = cfg
        self.schedule = LearnSchedule(cfg.every_h)
        self.job: LearnJob | None = None
        self.job_t_s = math.nan
        self.offer: Offer | None = None          # sent, waiting for the model node's answer
        self.runs = 0
        self.t_s = math.nan
        self.current_sha256 = prior_digest(cfg.prior_path) if cfg.prior_path else ""
        self.last = "idle"
        #: the twin learn starts from and tests against open loop: the type's, then the adopted unit's
        self.twin = cfg.twin
        #: the prior (and configuration) in use, learn's adaptive test: the node's, then the adopted one
        self.prior_path, self.config_path = cfg.prior_path, cfg.config_path

    @property
    def busy(self) -> bool:
        return self.job is not None or self.offer is not None

    def observe(self, t_s: float) -> None:
        self.t_s = t_s
        self.schedule.observe(t_s)

    def request(self) -> tuple[bool, str]:
        """A learning on demand: (accepted, one line)."""
        if self.busy:
            return False, f"busy: {self.last}"
        if self.schedule.t0 is None:
            return False, "no model instant seen yet: nothing recorded to learn from"
        self.schedule.request()
        return True, "learning requested: it starts within the learner's next poll"

    def poll(self, now_s: float) -> Offer | None:
        """Start a due learning, look at the running one; an Offer when learn adopted a prior."""
        if self.job is None and self.offer is None:
            why = self.schedule.take(busy=False)
            if why:
                self._start(why, now_s)
        if self.job is None:
            return None
        end = self.job.poll(now_s)
        if end is None:
            return None
        job, self.job = self.job, None
        return self._ended(job, end)

    def _start(self, why: str, now_s: float) -> None:
        self.job_t_s = self.t_s
        hours = self.schedule.hours(self.t_s)
        while True:
            self.runs += 1
            work = pathlib.Path(self.cfg.work_dir) / f"learn_{self.runs:03d}_{hours:.1f}h"
            if not work.exists():         # a restarted learner never reuses a folder
                break
        try:
            snap = snapshot_bag(pathlib.Path(self.cfg.recording), work / "recording")
        except (ValueError, OSError) as exc:
            self._audit("learn failed", f"snapshot of the recording: {exc}", work=str(work))
            return
        argv = learn_argv(self.cfg.command, snap, self.twin, work / "out", self.cfg.train_fraction * hours,
                          self.prior_path, self.config_path if self.prior_path else "")
        started = start_job(argv, work, self.cfg.timeout_s, now_s)
        if isinstance(started, JobEnd):
            self._audit("learn failed", started.reason, work=str(work))
            return
        self.job = started
        self.last = f"learning {self.runs} ({why}) on {hours:.1f} h recorded, started at model time {self.t_s:.0f} s"

    def _ended(self, job: LearnJob, end: JobEnd) -> Offer | None:
        work = str(job.work)
        if end.state is JobState.TIMED_OUT:
            self._audit("learn timed out", end.reason, work=work, wall_s=round(end.wall_s, 1))
            return None
        if end.state is JobState.FAILED:
            self._audit("learn failed", end.reason, work=work, wall_s=round(end.wall_s, 1))
            return None
        out = job.work / "out"
        try:
            decision = read_decision(out)
        except ReportError as exc:
            self._audit("learn failed", str(exc), work=work, wall_s=round(end.wall_s, 1))
            return None
        if not decision.adopt:
            self._audit("not adopted", decision.reason, decision.figures, work=work, wall_s=round(end.wall_s, 1))
            return None
        self.offer = Offer(decision.prior_path, decision.config_path, str(out / "report.json"),
                           prior_digest(decision.prior_path), decision.figures, decision.unit_twin)
        self.last = f"offering {decision.prior_path} to the model node"
        return self.offer

    def answered(self, accepted: bool, message: str, old_sha256: str, new_sha256: str) -> None:
        """The model node's answer to the offer (accepted: it warms and swaps it)."""
        offer, self.offer = self.offer, None
        if offer is None:
            return
        self.current_sha256 = old_sha256 or self.current_sha256
        self._audit("adoption sent" if accepted else "adoption refused", message,
                    offer.figures, new_sha=new_sha256 or offer.sha256, report=offer.report_path)
        if accepted:
            self.current_sha256 = new_sha256 or offer.sha256
            self.twin = offer.unit_twin or self.twin
            self.prior_path, self.config_path = offer.prior_path, offer.config_path

    def stop(self) -> None:
        """Kill a running learning (the node shuts down)."""
        if self.job is not None:
            self.job.kill()
            self._audit("learn failed", "the learner stopped while learn ran: killed", work=str(self.job.work))
            self.job = None

    def _audit(self, event: str, reason: str, figures: dict | None = None, new_sha: str = "", **extra) -> None:
        self.last = f"{event}: {reason}"
        if math.isfinite(self.job_t_s):
            extra["learn_started_model_time_s"] = self.job_t_s
        append_audit(self.cfg.audit_path, audit_record(event, self.t_s, self.current_sha256, new_sha, reason,
                                                       figures, source="learner", **extra))
