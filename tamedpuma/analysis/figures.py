"""Figures from run logs: ``python -m analysis.figures RUNS_DIR [--out DIR]`` (PNG and PDF).

- ``paths_<task>.png``: per scenario, the end-effector paths of every method with obstacles
  against PUMA's obstacle-free path (top view x–y and side view x–z), obstacles as circles at
  their first position, the goal as a star;
- ``clearance_psi_<task>.png``: clearance [m] and ψ/ψ₀ (the learned potential, normalised by its
  start value) over time, one thin line per run, coloured by method;
- ``success_timing.png``: success rate per method (paper and whole-body criteria), time to
  success [s] and controller time [ms] (median of each run), each with a 95% interval (Wilson
  for the rates, bootstrap for the times);
- ``scaling.png`` (only when a method was run at three or more obstacle counts up to 10 or more,
  the ``clutter.count`` sweep): controller time and success against the number of obstacles.

Everything is read from the MCAP logs alone (:mod:`tamedpuma.analysis.runs`).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from tamedpuma.analysis.runs import parse_and_load, runs_parser
from tamedpuma.analysis.stats import bootstrap_ci, rate_interval
from tamedpuma.analysis.tables import _labels, ordered_labels
from tamedpuma.errors import LogError
from tamedpuma.recording import read_mcap

REFERENCE = "puma"
_PLANES = (("x", "y", "top view"), ("x", "z", "side view"))


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"figure.dpi": 100, "savefig.dpi": 110, "font.size": 8,
                         "axes.titlesize": 8, "legend.fontsize": 7})
    return plt


def method_colors(labels) -> dict[str, tuple]:
    """A fixed colour per method label (paper order); PUMA dark grey (its obstacle-free
    reference path is drawn black and dashed)."""
    plt = _plt()
    cmap = plt.get_cmap("tab10")
    out, i = {}, 0
    for label in ordered_labels(labels):
        if label == REFERENCE:
            out[label] = (0.45, 0.45, 0.45, 1.0)
        else:
            out[label] = cmap(i % 10)
            i += 1
    return out


FORMATS = ("png", "pdf")


def _save(fig, out: Path, name: str) -> list[Path]:
    paths = [out / f"{name}.{fmt}" for fmt in FORMATS]
    for p in paths:
        fig.savefig(p, bbox_inches="tight")
    _plt().close(fig)
    return paths


def load_series(runs: pd.DataFrame, names=("clearance_m", "psi")) -> dict[str, pd.DataFrame]:
    """Per run path: its ``t`` and the scalars in ``names`` it logged (index step)."""
    out = {}
    for path in runs["path"]:
        try:
            sc = read_mcap(path).scalars
        except LogError:
            continue
        out[path] = sc[["t"] + [n for n in names if n in sc.columns]]
    return out


def _first_obstacles(path: str) -> pd.DataFrame:
    try:
        obs = read_mcap(path).obstacles
    except LogError:
        return pd.DataFrame(columns=["x", "y", "z", "radius"])
    return obs[obs["step"] == obs["step"].min()] if len(obs) else obs


def paths_figure(runs: pd.DataFrame, paths: dict, task: str, out: Path,
                 goals: dict | None = None) -> list[Path]:
    """``paths_<task>``: one column pair (top and side view) per scenario."""
    plt = _plt()
    labels = _labels(runs)
    colors = method_colors(labels)
    r = runs[runs["task"] == task]
    scenarios = sorted(set(r["scenario"]))
    cols = min(len(scenarios), 5)
    rows = int(np.ceil(len(scenarios) / cols))
    fig, axes = plt.subplots(2 * rows, cols, figsize=(2.6 * cols, 2.5 * 2 * rows), squeeze=False)
    for k, scenario in enumerate(scenarios):
        s = r[r["scenario"] == scenario]
        obstacle_runs = s[s["n_obstacles"] > 0]
        ref = s[(labels[s.index] == REFERENCE) & (s["n_obstacles"] == 0)]
        obstacles = _first_obstacles(obstacle_runs["path"].iloc[0]) if len(obstacle_runs) \
            else None
        for j, (a, b, view) in enumerate(_PLANES):
            ax = axes[2 * (k // cols) + j, k % cols]
            ia, ib = "xyz".index(a), "xyz".index(b)
            if obstacles is not None:
                for o in obstacles.itertuples():
                    ax.add_patch(plt.Circle((getattr(o, a), getattr(o, b)), o.radius,
                                            color=(0.85, 0.2, 0.2), alpha=0.35, lw=0))
            for row in ref.itertuples():
                p = paths[row.path]
                ax.plot(p[:, ia], p[:, ib], "k--", lw=1.2, label="PUMA, no obstacles")
            for idx, row in obstacle_runs.iterrows():
                p = paths[row["path"]]
                label = labels[idx]
                ax.plot(p[:, ia], p[:, ib], color=colors[label], lw=1.0, label=label)
                ax.plot(p[0, ia], p[0, ib], "o", color=colors[label], ms=3)
            if goals and scenario in goals:
                g = goals[scenario]
                ax.plot(g[ia], g[ib], "*", color=(0.1, 0.7, 0.2), ms=9, label="goal")
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_title(f"{scenario} ({view})")
            ax.set_xlabel(f"{a} [m]")
            ax.set_ylabel(f"{b} [m]")
            ax.grid(alpha=0.3)
    for ax in axes.ravel()[2 * len(scenarios):]:
        ax.axis("off")
    handles = {}
    for ax in axes.ravel():
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    fig.legend(handles.values(), handles.keys(), loc="upper center", ncol=len(handles),
               bbox_to_anchor=(0.5, 1.0 + 0.02 / rows))
    against = (" against PUMA's obstacle-free path"
               if ((labels[r.index] == REFERENCE) & (r["n_obstacles"] == 0)).any() else "")
    fig.suptitle(f"{task}: end-effector paths with obstacles{against}", y=1.0 + 0.06 / rows)
    fig.tight_layout()
    return _save(fig, out, f"paths_{task}")


def clearance_psi_figure(runs: pd.DataFrame, series: dict, task: str, out: Path) -> list[Path]:
    """``clearance_psi_<task>``: clearance and ψ/ψ₀ over time for the runs with obstacles."""
    plt = _plt()
    labels = _labels(runs)
    colors = method_colors(labels)
    r = runs[(runs["task"] == task) & (runs["n_obstacles"] > 0)]
    fig, (ax_c, ax_p) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    seen = set()
    any_psi = False
    for idx, row in r.iterrows():
        sc = series.get(row["path"])
        if sc is None:
            continue
        label = labels[idx]
        name = label if label not in seen else None
        seen.add(label)
        ax_c.plot(sc["t"], sc["clearance_m"], color=colors[label], lw=0.8, alpha=0.7,
                  label=name)
        if "psi" in sc and np.isfinite(sc["psi"]).any() and abs(sc["psi"].iloc[0]) > 0:
            any_psi = True
            ax_p.plot(sc["t"], sc["psi"] / sc["psi"].iloc[0], color=colors[label], lw=0.8,
                      alpha=0.7, label=label if f"psi:{label}" not in seen else None)
            seen.add(f"psi:{label}")
    ax_c.axhline(0.0, color="r", lw=0.8, ls=":")
    ax_c.set_ylabel("clearance [m]")
    ax_c.set_title(f"{task}: clearance of the closest body sphere (runs with obstacles)")
    ax_c.legend(loc="upper right")
    ax_c.grid(alpha=0.3)
    ax_p.set_ylabel("ψ / ψ₀")
    ax_p.set_xlabel("time [s]")
    ax_p.set_title("learned potential ψ along the run, over its start value")
    if any_psi:
        ax_p.legend(loc="upper right")
    else:
        ax_p.text(0.5, 0.5, "no run in this folder logs ψ (only FPM/CPM do)",
                  ha="center", va="center", transform=ax_p.transAxes, color="0.4")
    ax_p.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, out, f"clearance_psi_{task}")


def method_summary(runs: pd.DataFrame) -> pd.DataFrame:
    """Per method label, on its runs with obstacles (all its runs if it has none): success
    rates, time to success [s] and per-run median controller time [ms], each a
    :class:`~tamedpuma.analysis.stats.Interval` (95%: Wilson for the rates, bootstrap else)."""
    labels = _labels(runs)
    rows = []
    for label in ordered_labels(labels):
        r = runs[labels == label]
        scored = r[r["n_obstacles"] > 0] if (r["n_obstacles"] > 0).any() else r
        rows.append({
            "method": label, "runs": len(scored),
            "success_paper": rate_interval(scored["success_paper"].astype(float)),
            "success_whole_body": rate_interval(scored["success_whole_body"].astype(float)),
            "time_to_success_s": bootstrap_ci(
                scored.loc[scored["success_paper"], "time_to_success_s"]),
            "compute_ms_median": bootstrap_ci(scored["compute_ms_median"]),
        })
    return pd.DataFrame(rows)


def success_timing_figure(runs: pd.DataFrame, out: Path) -> list[Path]:
    plt = _plt()
    summary = method_summary(runs)
    colors = method_colors(summary["method"])
    x = np.arange(len(summary))
    fig, axes = plt.subplots(1, 3, figsize=(10, 3.2))

    def bars(ax, column, offset=0.0, width=0.8, hatch=None, label=None):
        for i, (m, iv) in enumerate(zip(summary["method"], summary[column])):
            if iv.n == 0:
                continue
            ax.bar(i + offset, iv.value, width, color=colors[m], alpha=0.85, hatch=hatch,
                   edgecolor="k", lw=0.5, label=label if i == 0 else None)
            ax.errorbar(i + offset, iv.value, yerr=[[iv.value - iv.low], [iv.high - iv.value]],
                        color="k", capsize=3, lw=1)

    bars(axes[0], "success_paper", -0.2, 0.4, label="paper")
    bars(axes[0], "success_whole_body", 0.2, 0.4, hatch="//", label="whole body")
    axes[0].set_ylim(0, 1.25)
    axes[0].set_yticks(np.linspace(0, 1, 6))
    axes[0].set_ylabel("success rate")
    axes[0].set_title("success (runs with obstacles), 95% CI")
    axes[0].legend(loc="upper center", ncol=2)
    bars(axes[1], "time_to_success_s")
    axes[1].set_ylabel("time to success [s]")
    axes[1].set_title("time to success (successful runs), 95% CI")
    bars(axes[2], "compute_ms_median")
    axes[2].set_ylabel("controller time [ms]")
    medians = [iv.value for iv in summary["compute_ms_median"] if iv.n]
    if medians and max(medians) > 30 * min(medians):  # bars on a log axis only when needed
        axes[2].set_yscale("log")
    axes[2].set_title("controller time (median per run), 95% CI")
    for ax in axes:
        ax.set_xticks(x, [f"{m}\n(n={n})" for m, n in zip(summary["method"], summary["runs"])])
        ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return _save(fig, out, "success_timing")


def has_scaling(runs: pd.DataFrame, min_counts: int = 3, min_largest: int = 10) -> bool:
    """Whether some method was run at ``min_counts`` or more obstacle counts reaching at least
    ``min_largest`` obstacles (the obstacle-count sweep, not the scenarios' own 0-3)."""
    g = runs.groupby(_labels(runs))["n_obstacles"]
    return bool(((g.nunique() >= min_counts) & (g.max() >= min_largest)).any())


def scaling_figure(runs: pd.DataFrame, out: Path) -> list[Path]:
    plt = _plt()
    labels = _labels(runs)
    colors = method_colors(labels)
    fig, (ax_t, ax_s) = plt.subplots(1, 2, figsize=(9, 3.3))
    for label in ordered_labels(labels):
        r = runs[labels == label]
        if r["n_obstacles"].nunique() < 3:
            continue
        g = r.groupby("n_obstacles")
        n = np.array(sorted(g.groups))
        med = [bootstrap_ci(g.get_group(k)["compute_ms_median"], np.median) for k in n]
        ax_t.errorbar(n, [m.value for m in med],
                      yerr=[[m.value - m.low for m in med], [m.high - m.value for m in med]],
                      color=colors[label], marker="o", ms=3, capsize=2, label=label)
        succ = [rate_interval(g.get_group(k)["success_paper"].astype(float)) for k in n]
        ax_s.errorbar(n, [s.value for s in succ],
                      yerr=[[s.value - s.low for s in succ], [s.high - s.value for s in succ]],
                      color=colors[label], marker="o", ms=3, capsize=2, label=label)
    ax_t.set_xscale("symlog", linthresh=1)
    ax_t.set_yscale("log")
    ax_t.set_xlabel("obstacles")
    ax_t.set_ylabel("controller time, median per run [ms]")
    ax_t.set_title("controller time against obstacle count (95% CI)")
    ax_s.set_xscale("symlog", linthresh=1)
    ax_s.set_ylim(0, 1.05)
    ax_s.set_xlabel("obstacles")
    ax_s.set_ylabel("success rate (paper)")
    ax_s.set_title("success against obstacle count (95% CI)")
    for ax in (ax_t, ax_s):
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    return _save(fig, out, "scaling")


def goal_positions(runs: pd.DataFrame) -> dict[str, np.ndarray]:
    """Per scenario: the goal position [m] at the first step (from the first run's /scene)."""
    from tamedpuma.recording.convert import mcap_records

    goals = {}
    for scenario, group in runs.groupby("scenario"):
        try:
            _, records = mcap_records(group["path"].iloc[0])
        except LogError:
            continue
        if records:
            goals[scenario] = records[0].goal_position
    return goals


def make_figures(runs: pd.DataFrame, paths: dict, out: Path,
                 formats: tuple[str, ...] = ("png", "pdf")) -> list[Path]:
    """Every figure the runs support; returns the files written (one per format)."""
    global FORMATS
    FORMATS = tuple(formats)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    series = load_series(runs)
    goals = goal_positions(runs)
    for task in sorted(set(runs["task"].dropna())):
        written += paths_figure(runs, paths, task, out, goals)
        written += clearance_psi_figure(runs, series, task, out)
    written += success_timing_figure(runs, out)
    if has_scaling(runs):
        written += scaling_figure(runs, out)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = runs_parser(__doc__, "output folder (default: RUNS/figures)")
    parser.add_argument("--formats", default="png,pdf",
                        help="comma-separated file formats (default: png,pdf)")
    got = parse_and_load(parser, argv)
    if got is None:
        return 2
    args, (runs, paths, _) = got
    formats = tuple(f.strip() for f in args.formats.split(",") if f.strip())
    written = make_figures(runs, paths, args.out or args.runs / "figures", formats)
    for p in written:
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
