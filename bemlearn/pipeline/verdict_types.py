"""The verdict of a run as a value: :class:`Verdict` and its :class:`Finding` (judged by
:func:`bemlearn.pipeline.verdict.judge_run`, read back by :class:`bemlearn.pipeline.run_metrics.RunMetrics`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["Finding", "Verdict", "EXIT_UNUSABLE", "EXIT_DEGRADED_STRICT", "SEVERITY_RANK"]

#: ``bemlearn run``'s exit status for an unusable run, and for a degraded one under ``--strict``.
EXIT_UNUSABLE = 3
EXIT_DEGRADED_STRICT = 4

#: Severities in order (a note does not change the status).
SEVERITY_RANK = {"note": -1, "ok": 0, "degraded": 1, "unusable": 2}


@dataclass(frozen=True)
class Finding:
    """One check that did not pass: its severity, a key and a sentence with the numbers."""

    severity: str
    check: str
    reason: str


@dataclass(frozen=True)
class Verdict:
    """The verdict of a run (:mod:`bemlearn.pipeline.verdict` lists its checks)."""

    status: str
    findings: tuple[Finding, ...] = field(default_factory=tuple)
    checked: tuple[str, ...] = field(default_factory=tuple)

    @property
    def reasons(self) -> list[str]:
        return [f.reason for f in self.findings]

    def to_dict(self) -> dict[str, Any]:
        """``{"status", "reasons", "findings": [{severity, check, reason}], "checked": [...]}``."""
        return {"status": self.status, "reasons": self.reasons,
                "findings": [{"severity": f.severity, "check": f.check, "reason": f.reason} for f in self.findings],
                "checked": list(self.checked)}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> Verdict:
        """The verdict :meth:`to_dict` wrote (``metrics.json``'s ``verdict``)."""
        findings = tuple(Finding(f["severity"], f["check"], f["reason"]) for f in doc.get("findings", []))
        return cls(doc["status"], findings, tuple(doc.get("checked", [])))

    def exit_status(self, *, strict: bool = False) -> int:
        """0 for ok (and degraded unless ``strict``), :data:`EXIT_UNUSABLE`, :data:`EXIT_DEGRADED_STRICT`."""
        if self.status == "unusable":
            return EXIT_UNUSABLE
        return EXIT_DEGRADED_STRICT if strict and self.status == "degraded" else 0

    def summary(self) -> str:
        """One line: ``Verdict: degraded — reason; reason``."""
        return f"Verdict: {self.status}" + (" — " + "; ".join(self.reasons) if self.findings else "")


