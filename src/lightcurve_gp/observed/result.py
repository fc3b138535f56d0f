"""One finished estimate on a light-curve file: every table, the verdict, the summary and the sentences to print.

:func:`finish` turns an :class:`~lightcurve_gp.observed.run.ObservedRun` into a :class:`FileResult` that a command
only writes and prints: the attitude history (:func:`~lightcurve_gp.observed.run.history_table`), the bank's members
(:func:`~lightcurve_gp.observed.run.bank_table`, when a bank ran), the bank's verdict
(:func:`~lightcurve_gp.observed.verdict.bank_verdict` modulo the file's exact ambiguity group), ``summary.json``'s
content (:func:`summary`) and the report in words (:meth:`FileResult.report`).
"""

from __future__ import annotations

from dataclasses import dataclass

from astropy.table import Table

from lightcurve_gp.observed.run import ObservedRun, bank_table, history_table, nis_summary
from lightcurve_gp.observed.verdict import BankVerdict, bank_verdict
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup

__all__ = ["FileResult", "finish", "summary"]


@dataclass
class FileResult:
    """What a run on a file produced.

    Attributes:
        run: the run (the reported filter's history, its start, the bank).
        history: the attitude history table (one row per sample).
        bank: the bank's members ranked, or ``None`` without a bank.
        verdict: the bank's verdict, or ``None`` without a bank.
        summary: ``summary.json``'s content (:func:`summary`).
        status: what ran, in words ("filter", "bank of 1024 filters", …).
    """

    run: ObservedRun
    history: Table
    bank: Table | None
    verdict: BankVerdict | None
    summary: dict
    status: str

    def report(self) -> list[str]:
        """The lines a command prints: the NIS against its band, the bank's best member and its verdict."""
        result, nis = self.summary, self.summary["nis"]
        lines = [f"{self.run.lc.source}: {result['samples']} samples over {result['span_s']:g} s; mean NIS "
                 f"{nis['mean']:.3f} over {nis['n']} updates, 95 % band {nis['band_95'][0]:.3f}-"
                 f"{nis['band_95'][1]:.3f} ({'consistent' if nis['in_band'] else 'outside the band'}); "
                 f"{100 * nis['share_above_3.84']:.1f} % of NIS above 3.84 (5 % expected)"]
        if self.run.bank is not None:
            best = result["bank"]["best"][0]
            lines.append(f"bank: {result['bank']['size']} filters in {self.run.bank.seconds:.1f} s; best member "
                         f"{best['member']} (weight {best['weight']:.3f}, log-likelihood "
                         f"{best['log_likelihood']:.1f})")
            lines += self.verdict.sentences(result["bank"]["size"])
        return lines


def finish(run: ObservedRun, *, record: dict, status: str, rho_reference: float | None,
           group: AmbiguityGroup | None, p0_deg: float | None = None) -> FileResult:
    """The finished result of ``run``.

    Args:
        run: the run on the file.
        record: the provenance (config, files, options, versions) kept in ``summary.json``'s ``run``.
        status: what ran, in words.
        rho_reference: the reference ρ the estimated offset is turned into ρ̂ with (``None``: no offset estimated).
        group: the exact ambiguity group of the file (:func:`~lightcurve_gp.observed.verdict.ambiguity_images`)
            whose images the bank's verdict counts as one answer; needed when a bank ran, else ``None``.
        p0_deg: the members' prior (``filter.p0_deg``): the verdict then says whether the bank covers SO(3)
            (:func:`~lightcurve_gp.observed.verdict.bank_coverage`).
    """
    verdict = None if run.bank is None else bank_verdict(run.bank, group, p0_deg=p0_deg)
    return FileResult(run=run, history=history_table(run, rho_reference),
                      bank=None if run.bank is None else bank_table(run.bank), verdict=verdict,
                      summary=summary(run, record, verdict), status=status)


def summary(run: ObservedRun, record: dict, verdict: BankVerdict | None = None) -> dict:
    """``summary.json``: the bank's verdict (``null`` without a bank), NIS statistics, timing, the bank's best
    members and its posterior's shape, and the provenance ``record``."""
    out = {"verdict": None if verdict is None else verdict.verdict,
           "light_curve": run.lc.source, "samples": int(run.lc.t.size), "span_s": float(run.lc.t[-1]),
           "per_sample_noise": run.lc.mag_err is not None, "nis": nis_summary(run.history),
           "geometry": "per-sample columns" if run.lc.geometry is not None else "TLE and site" if run.lc.has_tle
           else "config (fixed)",
           "initial_attitude": run.q_est0.tolist(), "seconds": run.seconds,
           "rejected_updates": int(run.history.rejected.sum()), "sqrt_fallbacks": int(run.history.fallbacks.sum())}
    if run.bank is not None:
        b = run.bank
        best = b.order[:len(b.kept.q_est)]
        out["bank"] = {"size": int(b.q0.shape[0]), "seconds": b.seconds, "kept_seconds": b.kept_seconds,
                       "pruned_to": None if b.survivors is None else int(b.survivors.numel()),
                       "best": [{"member": int(i), "q0": b.q0[i].tolist(),
                                 "log_likelihood": float(b.log_likelihood[i]), "weight": float(b.weights[i])}
                                for i in best]}
        if verdict is not None:
            out["bank"]["posterior"] = verdict.as_dict()
    out["run"] = record
    return out
