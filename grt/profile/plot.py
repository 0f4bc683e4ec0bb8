"""``profile.png``: success against deformation size, random and adversarial, with the S0 band and margins."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def profile_figure(profile: dict) -> plt.Figure:
    """The figure of a ``profile.json`` (the caller closes it): per size the random shapes' pooled score with
    its 95% interval (each shape a faint dot), each adversarial direction's tested sizes (filled: drop
    confirmed), S0 with its interval (band), the crash-margin line and the two margins."""
    fig, ax = plt.subplots(figsize=(9, 4.5), dpi=120)
    s0, low, high = profile["s0"], *profile["s0_ci95"]
    ax.axhspan(low, high, color="tab:blue", alpha=0.12, label=f"S0 = {s0:.2f} (95% band)")
    ax.axhline(s0, color="tab:blue", lw=1)
    ax.axhline(profile["threshold"], color="tab:blue", ls=":", lw=1,
               label=f"crash margin: {1 - profile['crash_margin']:.0%} of S0")
    rnd = profile["random"]
    if rnd:
        x = [r["size_mm"] for r in rnd]
        y = [r["score"] for r in rnd]
        err = _bars(y, [r["ci95"] for r in rnd])
        ax.errorbar(x, y, yerr=err, fmt="-o", color="tab:gray", capsize=3,
                    label=f"random ({profile['shapes']} shapes x {profile['trials']} episodes per size)")
        for r in rnd:
            ax.scatter([r["size_mm"]] * len(r["shapes"]), [s["score"] for s in r["shapes"]], s=8, color="tab:gray",
                       alpha=0.35)
    colors = ["tab:red", "tab:orange", "tab:purple", "tab:brown"]
    for d, color in zip(profile["adversarial"], colors * 4, strict=False):
        levels = sorted(d["levels"], key=lambda v: v["size_mm"])
        if not levels:
            continue
        x = [v["size_mm"] for v in levels]
        y = [v["score"] for v in levels]
        err = _bars(y, [v["ci95"] for v in levels])
        ax.errorbar(x, y, yerr=err, fmt="-", color=color, capsize=3, label=f"adversarial: rank-{d['rank']} direction")
        for v in levels:
            ax.scatter([v["size_mm"]], [v["score"]], s=30, color=color if v["confirmed"] else "white",
                       edgecolors=color, zorder=3)
    m = profile["margins"]
    if m.get("random_mm"):
        ax.axvline(m["random_mm"], color="tab:gray", ls="--", lw=1,
                   label=f"random margin {m['random_mm']:g} mm" + (" (or more)" if m.get("random_beyond") else ""))
    if m.get("adversarial_mm"):
        ax.axvline(m["adversarial_mm"], color="tab:red", ls="--", lw=1,
                   label=f"adversarial margin {m['adversarial_mm']:g} mm")
    ax.set_xscale("log")
    ax.set_xlabel("deformation size: largest surface displacement (mm)")
    ax.set_ylabel("success rate" if not profile.get("score_unit") else f"mean {profile['score_name']}")
    ax.set_title(f"{profile['task']} / {profile['object']} / {profile['policy']}: robustness profile")
    ax.set_ylim(-0.03, max(1.03, high + 0.03))
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    return fig


def _bars(scores: list[float], intervals: list) -> list[list[float]]:
    """Matplotlib's ``yerr`` (below, above) of scores with their 95% intervals, never negative (an interval
    from an older profile.json may leave a score a rounding error outside it)."""
    return [[max(0.0, s - ci[0]) for s, ci in zip(scores, intervals, strict=True)],
            [max(0.0, ci[1] - s) for s, ci in zip(scores, intervals, strict=True)]]


def plot_profile(profile: dict, path: Path) -> Path:
    """Save :func:`profile_figure` to ``path``."""
    fig = profile_figure(profile)
    fig.savefig(path, format="png")
    plt.close(fig)
    return Path(path)
