"""``summary.md`` and plots from ``results.jsonl`` rows (``harness``): the paper-style table per method.

One table row per *variant*: method + ablation + guide + encoder, because a number from the oracle
guide or a random encoder must never be read as a text-guided, real-CLIP number. Plots are PNG
(matplotlib, Agg): semantic score vs intersection (the paper's trade-off figure), the ADD-S CDF, and
time per case.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from ctp_core.metrics import PLACEMENT_IOU, PLACEMENT_RADIUS, SUCCESS_ADDS

PLOTS = {"tradeoff": "tradeoff.png", "pose_cdf": "pose_cdf.png", "time": "time_per_case.png"}


def variant(row: dict) -> str:
    """The label a row is grouped and plotted under, e.g. ``ctp[no-icp] oracle/random:ViT-B-32 (default)``; rows of
    the scale protocol say so (``... (default, scale protocol)``)."""
    name = row["method"] + (f"[{row['ablation']}]" if row.get("ablation") else "")
    if row.get("guide") == "pixels":
        name += " pixels (upper bound, no encoder)"
    elif row.get("guide"):
        name += f" {row['guide']}/{row['encoder']}"
    notes = [row["preset"]] if row.get("preset") else []
    if row.get("protocol") == "scale":
        notes.append("scale protocol")
    if row.get("copies"):
        notes.append(f"{row['copies']} copies")
    if notes:
        name += f" ({', '.join(notes)})"
    return name


def _groups(rows: list[dict]) -> dict[str, list[dict]]:
    groups: dict[str, list[dict]] = defaultdict(list)
    for row in rows:
        groups[variant(row)].append(row)
    return dict(groups)


def _values(rows: list[dict], key: str) -> np.ndarray:
    vals = [r["metrics"].get(key) for r in rows if r.get("status") == "ok"]
    return np.array([float(v) for v in vals if v is not None], dtype=float)


def _semantic(rows: list[dict], spec: str) -> np.ndarray:
    vals = [r["metrics"]["semantic"].get(spec) for r in rows if r.get("status") == "ok"]
    return np.array([v for v in vals if v is not None], dtype=float)


def _times(rows: list[dict]) -> np.ndarray:
    return np.array([r["time_s"] for r in rows if r.get("status") == "ok"], dtype=float)


def _mean_median(v: np.ndarray, digits: int = 3) -> str:
    return "–" if v.size == 0 else f"{v.mean():.{digits}f} / {np.median(v):.{digits}f}"


def _median_spread(v: np.ndarray, digits: int = 3) -> str:
    """Median and the interquartile range: the scale error's cell (a few cases far off would swamp a mean)."""
    if v.size == 0:
        return "–"
    low, mid, high = np.quantile(v, [0.25, 0.5, 0.75])
    return f"{mid:.{digits}f} [{low:.{digits}f}–{high:.{digits}f}]"


def _rate(flags: list[bool]) -> str:
    return f"{100 * np.mean(flags):.0f}% ({sum(flags)}/{len(flags)})" if flags else "–"


def _encoders(rows: list[dict]) -> list[str]:
    return sorted({spec for r in rows if r.get("status") == "ok" for spec in r["metrics"]["semantic"]})


def table(rows: list[dict]) -> str:
    """The Markdown table: per variant, mean / median of every metric over its ok rows; where a row comes from the
    scale protocol, the scale error |ln(found / reference)| as median [interquartile range]."""
    specs = _encoders(rows)
    scaled = any(r.get("protocol") == "scale" for r in rows)
    copied = any(r.get("copies") for r in rows)
    head = ["variant", "ok/runs", "success", "placement", "placement@k", "relation holds", "stable", "valid",
            *(["copies hold", "sets apart"] if copied else []),
            "ADD-S", "rot err °", "trans err", *(["scale err"] if scaled else []), "IoU", "contact",
            *[f"semantic {s}" for s in specs], "time s", "CLIP images"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, group in sorted(_groups(rows).items()):
        ok = [r for r in group if r.get("status") == "ok"]
        success = [r["metrics"]["success"] for r in ok if "success" in r["metrics"]]
        placed = [r["metrics"]["placement_success"] for r in ok if "placement_success" in r["metrics"]]
        # None: no relation read from the prompt (or, for stable, not a resting one); rows before them lack the keys
        related = [r["metrics"]["relation_holds"] for r in ok if r["metrics"].get("relation_holds") is not None]
        steady = [r["metrics"]["stable"] for r in ok if r["metrics"].get("stable") is not None]
        at_k = [r["metrics"]["placement_at_k"] for r in ok if "placement_at_k" in r["metrics"]]
        valid = [r["metrics"]["valid"] for r in ok if r["metrics"].get("valid") is not None]
        clip = np.array([r.get("clip_images", 0) for r in ok], dtype=float)
        cells = [
            name, f"{len(ok)}/{len(group)}",
            _rate(success), _rate(placed), _rate(at_k), _rate(related), _rate(steady), _rate(valid),
            *(_copies(ok) if copied else []),
            _mean_median(_values(group, "adds")), _mean_median(_values(group, "rotation_error_deg"), 1),
            _mean_median(_values(group, "translation_error")),
            *([_median_spread(_values(group, "scale_error"))] if scaled else []),
            _mean_median(_values(group, "iou"), 4),
            _mean_median(_values(group, "contact"), 4), *[_mean_median(_semantic(group, s), 4) for s in specs],
            _mean_median(_times(group), 1), f"{clip.mean():.0f}" if clip.size else "–",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _copies(ok: list[dict]) -> list[str]:
    """Several of a kind: the copies whose relation holds, over every copy judged; the sets with no two copies
    intersecting. "–" for rows of one copy."""
    copies = [c["holds"] for r in ok if r.get("copy_set") for c in r["copy_set"]["per_copy"] if c["holds"] is not None]
    apart = [r["copy_set"]["set"]["none_intersect"] for r in ok if r.get("copy_set")]
    return [_rate(copies), _rate(apart)]


def per_case(rows: list[dict]) -> str:
    """ADD-S (IoU) of every case x variant, mean over inits: where each method wins or fails."""
    groups = _groups(rows)
    names = sorted(groups)
    cases = sorted({r["case"] for r in rows})
    lines = ["| case | " + " | ".join(names) + " |", "|" + "---|" * (len(names) + 1)]
    for case in cases:
        cells = []
        for name in names:
            ok = [r for r in groups[name] if r["case"] == case]
            adds, iou = _values(ok, "adds"), _values(ok, "iou")
            if iou.size == 0:
                cells.append(next((r["status"] for r in ok), "–"))
            else:
                cells.append((f"{adds.mean():.3f}" if adds.size else "–") + f" ({iou.mean():.4f})")
        lines.append(f"| {case} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_tradeoff(rows: list[dict], path: Path) -> bool:
    """Semantic score (first encoder) vs IoU, every run and each variant's mean; False if no scores."""
    specs = _encoders(rows)
    if not specs:
        return False
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for i, (name, group) in enumerate(sorted(_groups(rows).items())):
        ok = [r for r in group if r.get("status") == "ok" and r["metrics"]["semantic"].get(specs[0]) is not None]
        if not ok:
            continue
        x = np.array([r["metrics"]["iou"] for r in ok])
        y = np.array([r["metrics"]["semantic"][specs[0]] for r in ok])
        colour = f"C{i % 10}"
        ax.scatter(x, y, s=14, alpha=0.4, color=colour)
        ax.scatter([x.mean()], [y.mean()], s=90, marker="*", color=colour, edgecolor="k", label=name)
    ax.set_xlabel("intersection Vol(A∩B)/Vol(A∪B) (lower is better)")
    ax.set_ylabel(f"semantic score, {specs[0]} (higher is better)")
    ax.set_title("semantic score vs intersection (star: mean)")
    ax.legend(fontsize=7)
    _save(fig, path)
    return True


def plot_pose_cdf(rows: list[dict], path: Path) -> bool:
    """Fraction of runs with ADD-S below x, per variant; False if no row has a reference."""
    groups = {name: _values(g, "adds") for name, g in sorted(_groups(rows).items())}
    groups = {k: v for k, v in groups.items() if v.size}
    if not groups:
        return False
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for name, v in groups.items():
        ax.ecdf(np.maximum(v, 1e-4), label=name)  # floor: a perfect pose still shows on the log axis
    ax.axvline(SUCCESS_ADDS, color="k", ls="--", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("ADD-S (relative to the source diagonal)")
    ax.set_ylabel("fraction of runs")
    ax.set_ylim(0, 1.02)
    ax.set_title(f"pose error CDF (dashed: success at {SUCCESS_ADDS})")
    ax.legend(fontsize=7)
    _save(fig, path)
    return True


def plot_times(rows: list[dict], path: Path) -> bool:
    """Wall time per case, one bar per variant (mean over inits)."""
    groups = _groups(rows)
    cases = sorted({r["case"] for r in rows if r.get("status") == "ok"})
    if not cases:
        return False
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(max(6, 0.6 * len(cases) * max(1, len(groups)) / 2), 4.5))
    width = 0.8 / max(1, len(groups))
    for i, (name, group) in enumerate(sorted(groups.items())):
        times = [_times([r for r in group if r["case"] == c]) for c in cases]
        means = [t.mean() if t.size else np.nan for t in times]
        ax.bar(np.arange(len(cases)) + i * width, means, width, label=name)
    ax.set_xticks(np.arange(len(cases)) + 0.4 - width / 2, cases, rotation=60, ha="right", fontsize=7)
    ax.set_yscale("log")
    ax.set_ylabel("seconds per run")
    ax.set_title("time per case")
    ax.legend(fontsize=7)
    _save(fig, path)
    return True


def _save(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _notes(rows: list[dict]) -> list[str]:
    notes = []
    # a skipped case has no guide description (None): sort as text so that it never costs the run its summary
    guides = sorted({(r["guide"], r["encoder"], r.get("guide_description")) for r in rows if r.get("guide")},
                    key=lambda g: tuple(str(v) for v in g))
    for guide, encoder, description in guides:
        notes.append(f"guide `{guide}` with encoder `{encoder}` ({description})")
    if any(r["method"] == "geometry" or (r["method"] == "ctp" and not r.get("guide")) for r in rows):
        notes.append("`geometry` (and ctp without guidance) uses no encoder: lambda_clip = 0")
    methods = defaultdict(int)
    for r in rows:
        if r.get("status") == "ok":
            methods[r["metrics"]["iou_method"]] += 1
    if methods:
        notes.append("intersection: " + ", ".join(f"{n} runs `{m}`" for m, n in sorted(methods.items()))
                     + " (exact = manifold3d booleans; winding = winding-number grid estimate, meshes not closed)")
    for note in sorted({n for r in rows for n in (r.get("metric_notes") or {}).values()}):
        notes.append(note)
    for r in rows:
        if r.get("status") != "ok":
            notes.append(f"{r['case']} init {r['init']} {variant(r)}: {r.get('status')}: {r.get('error')}")
    return notes


def write_summary(rows: list[dict], out: Path, commands: list[str] = ()) -> Path:
    """Write ``summary.md`` and the plots into ``out``; returns the summary's path."""
    import matplotlib

    matplotlib.use("Agg")
    out = Path(out)
    made = {
        "tradeoff": plot_tradeoff(rows, out / PLOTS["tradeoff"]),
        "pose_cdf": plot_pose_cdf(rows, out / PLOTS["pose_cdf"]),
        "time": plot_times(rows, out / PLOTS["time"]),
    }
    cases = sorted({r["case"] for r in rows})
    parts = ["# Benchmark summary", ""]
    if commands:
        parts += ["```", *commands, "```", ""]
    parts += [f"{len(cases)} cases, {len(rows)} runs. Cells are mean / median over runs; success is "
              f"ADD-S ≤ {SUCCESS_ADDS} (cases with a reference only); placement is the centroid "
              f"within {PLACEMENT_RADIUS} source diagonals of the reference and IoU ≤ {PLACEMENT_IOU}; "
              "placement@k is any of the run's alternatives (the answer first) placed so; "
              "relation holds is the answer judged by the relation the priors read from the prompt "
              "(ctp_core/relations/predicates.py, docs/relations.md) in the reference's frame (the case's files as "
              "they are, never turned as a run may turn them), stable its centre of mass over its support (resting "
              "relations only), valid the relation holding, stable where that applies and IoU ≤ "
              f"{PLACEMENT_IOU} (unless the relation goes into the target), each over the runs where it applies; "
              "pose errors are relative to the source "
              "diagonal; contact is the closest surface distance over the target's longest side.", "",
              table(rows), "", "## Per case: ADD-S (IoU)", "", per_case(rows), "", "## Notes", ""]
    parts += [f"- {n}" for n in _notes(rows)]
    parts += ["", "## Plots", ""]
    for key, name in PLOTS.items():
        parts.append(f"![{key}]({name})" if made[key] else f"- {key}: not drawn (no data for it)")
    path = out / "summary.md"
    path.write_text("\n".join(parts) + "\n")
    return path
