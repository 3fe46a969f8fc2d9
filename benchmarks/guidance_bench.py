"""Cost and precision of the guidance model on this machine; prints one JSON line.

Measures what decides the CPU autocast default and the forward-only runtime default (see
ctp_core/guidance.py, ctp_core/runtime.py): forward+backward of a step's views in fp32 and bf16
(bf16 only where the CPU has it natively), and forward-only scoring (``Guide.score``, the text-guided
scoring path) in ms per image at batch 1, 8 and 32 for torch fp32, torch bf16 (native only), ONNX
Runtime fp32 and ONNX Runtime int8, all interleaved in one run (one warm-up round first; medians of
``--repeats`` rounds, and per-round ratios to torch fp32, which load drift cannot bias). Precision:
the largest image-text cosine change to torch fp32 over 64 x 8 = 512 pairs (bounds: bf16 1e-2, ONNX
fp32 1e-4), how well bf16 keeps the pixel gradient's direction, and for int8 the rank agreement with
torch fp32 over ``--poses`` renders of random candidate poses of one pair (Spearman >= 0.95 and at
least 8 of the top 10 kept). Also the fixed costs a worker pays once: ``import transformers``,
building the model, exporting the ONNX towers (or loading them from the cache). The load average
before and after is printed: the machine may be shared.

    OMP_WAIT_POLICY=PASSIVE python benchmarks/guidance_bench.py --spec random:ViT-B-32 \
        --case ../shared/bench/pairbench3d/coffee_cup_with_plate --table
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch

PROMPTS = [
    "a cherry on top of a sundae", "a hat on a dog", "a lamp on a desk", "an arrow stuck in a target",
    "a candle on a cake", "a cup on a saucer", "a bird on a branch", "a knife cutting an apple",
]


def scenes(n: int, size: int, seed: int) -> torch.Tensor:
    """(n, 3, size, size) render-like images: two flat-coloured ellipses on a white background."""
    g = torch.Generator().manual_seed(seed)
    axis = torch.linspace(-1, 1, size)
    yy, xx = torch.meshgrid(axis, axis, indexing="ij")
    out = torch.ones(n, 3, size, size)
    for _ in range(2):
        c = torch.rand(n, 2, 1, 1, generator=g) * 1.2 - 0.6
        r = torch.rand(n, 2, 1, 1, generator=g) * 0.4 + 0.15
        inside = ((((xx - c[:, :1]) / r[:, :1]) ** 2 + ((yy - c[:, 1:]) / r[:, 1:]) ** 2) < 1)
        out = torch.where(inside, torch.rand(n, 3, 1, 1, generator=g), out)
    return out


def seconds(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def loadavg() -> list[float] | None:
    try:
        return [float(v) for v in Path("/proc/loadavg").read_text().split()[:3]]
    except OSError:
        return None


def candidate_renders(case: Path | None, count: int, size: int, seed: int) -> tuple[torch.Tensor, str]:
    """(count, 3, size, size) renders of one pair at random candidate poses (one framing view each), and its prompt.

    ``case`` is a bench case folder (case.json); without one, a box (target) and a sphere (source).
    """
    import numpy as np
    import trimesh

    from ctp_core import pairs, render
    from ctp_core.bench import protocol
    from ctp_core.render import cameras

    if case is not None:
        from ctp_core.bench.cases import read_case

        c = read_case(case / "case.json")
        (target, source), prompt = c.load(), c.prompt
    else:
        target, source = trimesh.creation.box((2.0, 0.2, 1.0)), trimesh.creation.icosphere(2, 0.3)
        prompt = "a ball on a table"
    pair = pairs.prepare_pair(target, source, samples=100, seed=0, canonicalise=False)
    rng = np.random.default_rng(seed)
    starts = protocol.random_starts(target.bounds, source.bounds, 1.0, count, rng, distance=(0.3, 1.2))
    out = []
    with torch.no_grad():
        for chunk in range(0, count, 50):
            m = torch.tensor(np.stack([pair.local_to_normalised(p) for p in starts[chunk:chunk + 50]]),
                             dtype=torch.float32)
            posed = pair.source_vertices @ m[:, :3, :3].transpose(1, 2) + m[:, None, :3, 3]
            verts = pair.scene_vertices(posed)
            out.append(render.render(pair.mesh, verts, cameras.framing_cameras(verts, 1, size))[:, 0])
    return torch.cat(out), prompt


def rank_agreement(reference: torch.Tensor, other: torch.Tensor, top: int = 10) -> dict:
    from scipy.stats import spearmanr

    kept = set(reference.topk(top).indices.tolist()) & set(other.topk(top).indices.tolist())
    return {"spearman": round(float(spearmanr(reference.numpy(), other.numpy()).statistic), 4),
            f"top{top}_kept": len(kept)}


def main() -> None:
    args = _arguments()
    load_start = loadavg()
    bench = _Runtimes(args.spec)
    bench.use("torch_fp32")  # the reference everywhere: the text is encoded once, in torch fp32
    text = bench.guide.encode_text(PROMPTS)
    views = scenes(args.views, args.size, seed=1)
    batches = [int(b) for b in args.batches.split(",")]
    fwd_bwd, ms, ratio = _timed(bench, text, views, batches, args)
    cos, grad, pose_scores, renders = _precision(bench, text, views, args)

    result = {"spec": args.spec, "threads": bench.threads, "native_bf16": bench.native, "views": args.views,
              "size": args.size, "loadavg_start": load_start, "import_transformers_s": round(bench.import_s, 3),
              "build_s": round(bench.build_s, 3), "onnx_export_or_load_s": round(bench.export_s, 3),
              "onnx_dir": str(bench.onnx_dir)}
    result.update({f"fwd_bwd_s_{n.split('_')[1]}": round(statistics.median(v), 3) for n, v in fwd_bwd.items()})
    result["ms_per_image"] = {b: {n: round(statistics.median(v), 2) for n, v in ms[b].items()} for b in batches}
    result["speedup_vs_torch_fp32"] = {b: {n: round(statistics.median(v), 2) for n, v in ratio[b].items()
                                           if n != "torch_fp32"} for b in batches}
    _precision_figures(result, cos, grad)
    result["ranking"] = {"case": str(args.case) if args.case else "primitives", "poses": len(renders),
                         "score_range_fp32": [round(float(pose_scores["torch_fp32"].min()), 4),
                                              round(float(pose_scores["torch_fp32"].max()), 4)],
                         **{n: rank_agreement(pose_scores["torch_fp32"], v) for n, v in pose_scores.items()
                            if n != "torch_fp32"}}
    result["loadavg_end"] = loadavg()
    print(json.dumps(result))
    if args.table:
        print(markdown(result, batches, list(bench.runtimes)), file=sys.stderr)


def _arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", default="random:ViT-B-32")
    parser.add_argument("--views", type=int, default=8, help="images per forward+backward (a step's views)")
    parser.add_argument("--size", type=int, default=224, help="render resolution fed to the guide")
    parser.add_argument("--batches", default="1,8,32", help="forward-only batch sizes")
    parser.add_argument("--compare-images", type=int, default=64, help="images for the cosine comparison")
    parser.add_argument("--poses", type=int, default=500, help="candidate-pose renders for the int8 ranking")
    parser.add_argument("--case", type=Path, help="bench case folder for the candidate poses (default: primitives)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--table", action="store_true", help="also print a Markdown table to stderr")
    return parser.parse_args()


class _Runtimes:
    """The guide under test and the runtimes it is switched between (``runtimes``: name -> (encoders, autocast),
    encoders None for torch), with the fixed costs a worker pays once: ``import transformers``, building the model,
    exporting the ONNX towers or loading them from the cache."""

    def __init__(self, spec: str):
        start = time.perf_counter()
        import transformers  # noqa: F401  (timed: a worker pays this once per process)

        self.import_s = time.perf_counter() - start
        from ctp_core.guide.guidance import cpu_has_fast_bf16
        from ctp_core.guide.loaders import load_guide

        start = time.perf_counter()
        self.guide = load_guide(spec, autocast=False)
        self.build_s = time.perf_counter() - start
        self.native = cpu_has_fast_bf16()
        self.threads = torch.get_num_threads()
        start = time.perf_counter()
        self.guide.use_runtime("onnx", self.threads)
        onnx32 = self.guide.encoders
        self.export_s = time.perf_counter() - start
        self.guide.use_runtime("onnx-int8", self.threads)
        onnx8 = self.guide.encoders
        if onnx32 is None or onnx8 is None:
            raise SystemExit("ONNX Runtime unavailable (see the warning above)")
        self.onnx_dir = onnx32.directory
        self.runtimes = {"torch_fp32": (None, False), **({"torch_bf16": (None, True)} if self.native else {}),
                         "onnx_fp32": (onnx32, False), "onnx_int8": (onnx8, False)}
        self.grad_names = [n for n in ("torch_fp32", "torch_bf16") if n in self.runtimes]

    def use(self, name: str) -> None:
        self.guide.encoders, self.guide.autocast = self.runtimes[name]

    def step(self, views: torch.Tensor, text: torch.Tensor) -> torch.Tensor:
        """One optimiser step's forward+backward of ``views``; the pixel gradient."""
        images = views.clone().requires_grad_(True)
        (-(self.guide.encode_images(images) @ text[0]).mean()).backward()
        return images.grad


def _timed(bench: _Runtimes, text: torch.Tensor, views: torch.Tensor, batches: list[int],
           args: argparse.Namespace) -> tuple[dict, dict, dict]:
    """Seconds of a step's forward+backward per gradient runtime; per batch size, each runtime's forward-only ms per
    image and its speed-up over torch fp32 (per round): ``--repeats`` rounds after a warm-up one."""
    batch_images = {b: scenes(b, args.size, seed=2 + b) for b in batches}
    fwd_bwd = {n: [] for n in bench.grad_names}
    ms = {b: {n: [] for n in bench.runtimes} for b in batches}
    ratio = {b: {n: [] for n in bench.runtimes} for b in batches}
    # Interleave everything, one warm-up round first: on a shared machine load drifts, and alternating
    # keeps it from favouring whichever runtime ran in the quieter minute; ratios are taken per round.
    for round_ in range(args.repeats + 1):
        for name in bench.grad_names:
            bench.use(name)
            elapsed = seconds(lambda: bench.step(views, text))
            if round_:
                fwd_bwd[name].append(elapsed)
        for b in batches:
            this_round = {}
            for name in bench.runtimes:
                bench.use(name)
                this_round[name] = seconds(lambda b=b: bench.guide.score(batch_images[b], text[0], batch_size=b))
            if round_:
                for name, elapsed in this_round.items():
                    ms[b][name].append(1000 * elapsed / b)
                    ratio[b][name].append(this_round["torch_fp32"] / elapsed)
    return fwd_bwd, ms, ratio


def _precision(bench: _Runtimes, text: torch.Tensor, views: torch.Tensor,
               args: argparse.Namespace) -> tuple[dict, dict, dict, torch.Tensor]:
    """Per runtime: the image-text cosines of ``--compare-images`` scenes, the pixel gradient of a step (gradient
    runtimes), the scores of ``--poses`` candidate renders against their prompt; and those renders."""
    compare = scenes(args.compare_images, args.size, seed=3)
    cos, grad = {}, {}
    for name in bench.runtimes:
        bench.use(name)
        cos[name] = bench.guide.score(compare, text)
    for name in bench.grad_names:
        bench.use(name)
        grad[name] = bench.step(views, text).flatten()
    renders, prompt = candidate_renders(args.case, args.poses, args.size, seed=4)
    bench.use("torch_fp32")
    prompt_emb = bench.guide.encode_text([prompt])[0]
    pose_scores = {}
    for name in bench.runtimes:
        bench.use(name)
        pose_scores[name] = bench.guide.score(renders, prompt_emb)
    return cos, grad, pose_scores, renders


def _precision_figures(result: dict, cos: dict, grad: dict) -> None:
    """The cosine changes to torch fp32 and, with bf16, its gradient's direction and its step's speed-up, in
    ``result``."""
    result["max_abs_cos_diff"] = {n: float((cos[n] - cos["torch_fp32"]).abs().max()) for n in cos
                                  if n != "torch_fp32"}
    result["cos_pairs"] = cos["torch_fp32"].numel()
    result["cos_range_fp32"] = [round(float(cos["torch_fp32"].min()), 4), round(float(cos["torch_fp32"].max()), 4)]
    if "torch_bf16" in grad:
        result["grad_cos_bf16_fp32"] = round(float(torch.nn.functional.cosine_similarity(
            grad["torch_bf16"].double(), grad["torch_fp32"].double(), dim=0)), 5)
        result["speedup_fwd_bwd"] = round(result["fwd_bwd_s_fp32"] / result["fwd_bwd_s_bf16"], 2)


def markdown(result: dict, batches: list[int], names: list[str]) -> str:
    head = "| runtime | " + " | ".join(f"batch {b} ms/image (× torch fp32)" for b in batches) + \
        f" | max abs Δcos ({result['cos_pairs']} pairs) | Spearman / top-10 kept |"
    lines = [head, "|---" * (len(batches) + 3) + "|"]
    for n in names:
        cells = [f"{result['ms_per_image'][b][n]}" + (f" ({result['speedup_vs_torch_fp32'][b][n]}×)"
                                                      if n != "torch_fp32" else "") for b in batches]
        diff = f"{result['max_abs_cos_diff'][n]:.1e}" if n != "torch_fp32" else "reference"
        rank = result["ranking"].get(n)
        rank = f"{rank['spearman']} / {rank['top10_kept']}" if rank else "reference"
        lines.append(f"| {n.replace('_', ' ')} | " + " | ".join(cells) + f" | {diff} | {rank} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
