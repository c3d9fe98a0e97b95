"""Table 1 on still targets with the shipped models, without CLIP: every method, ours against Nearest Neighbour.

A thin wrapper around ``shadow-studio evaluate``: collects the Random/Nearest Neighbour training shards first when
they are missing (``collect --resolution 128 --n 50000 --out data/sx128``), runs the evaluation with the studio's
method (and, with ``--paper``, again with the paper's: sampled search batch, the self-model's best, hill climbing
8 × 1000), prints the Markdown table(s), and last a JSON object: per method its mean Total, IoU loss and seconds per
target, the time to the first answer, the ratios Ours/Nearest Neighbour (Total and IoU loss, measured in the same
run; below 1 means ours is better), the share of refined poses in collision, and the paper configuration's row
(with ``--paper`` also one Markdown table holding both configurations' rows).

    python benchmarks/bench_table1.py [--targets DIR|FILES...] [--per-folder 1] [--out runs/table1] [--paper]
                                      [-- extra evaluate args]
    python benchmarks/bench_table1.py --targets ../shared/targets/mpeg7 --per-folder '' --per-class 1 \
        --out runs/table1_mpeg7                      # one image of each of the 12 MPEG-7 classes
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ASL = ROOT.parent / "shared" / "targets" / "asl"
CPU_BUDGET = ["--search-batch", "32", "--search-iterations", "150"]  # CPU_SEARCH: the paper configuration on 2 cores


PRESET_FLAGS = {  # the two configurations of the table, as `evaluate` flags
    "studio": ["--preset", "studio"],
    "paper": ["--preset", "paper", *CPU_BUDGET],  # the paper's method at the CPU budget, not its GPU sizes
}


def evaluate(cli: list[str], args: argparse.Namespace, out: Path, method: str) -> dict[str, dict]:
    cmd = [*cli, "evaluate", *args.targets, "--out", str(out), "--nn-data", args.data, "--no-clip", "--quiet",
           *PRESET_FLAGS[method], *args.extra]  # fmt: skip
    if args.per_folder:
        cmd += ["--per-folder", args.per_folder]
    if args.per_class:
        cmd += ["--per-class", args.per_class]
    done = subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.PIPE, text=True)
    print(Path(out, "table1.md").read_text())
    return {r["method"]: r for r in json.loads(done.stdout.strip().splitlines()[-1])["rows"]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--targets", nargs="+", default=[str(ASL)], help="target folders/files (default ../shared/targets/asl)"
    )
    parser.add_argument("--per-folder", default="1", help="images per sub-folder (default 1: one per letter; '' = all)")
    parser.add_argument("--per-class", default="", help="images per class, the name before its last '-' (MPEG-7)")
    parser.add_argument("--data", default=str(ROOT / "data" / "sx128"), help="training shards (made when missing)")
    parser.add_argument("--out", default=str(ROOT / "runs" / "table1"), help="folder for the table files")
    parser.add_argument(
        "--paper",
        action="store_true",
        help="also run the paper's configuration (--preset paper at the CPU budget 32 × 150)",
    )
    parser.add_argument("extra", nargs="*", help="more `shadow-studio evaluate` options, after --")
    args = parser.parse_args()
    cli = [sys.executable, "-m", "studio.cli.main"]
    if not Path(args.data).is_dir():
        collect = [*cli, "collect", "--resolution", "128", "--n", "50000", "--out", args.data, "--quiet"]
        subprocess.run(collect, check=True, cwd=ROOT)
    rows = evaluate(cli, args, Path(args.out), "studio")
    ours, nn = rows["Ours"], rows["Nearest Neighbour"]
    summary = {
        "targets": ours["targets"],
        "methods": {
            m: {
                "total": round(r["total"], 4),
                "iou_loss": round(r["iou_loss"], 4),
                "seconds_per_target": round(r["seconds"], 3),
                "collide_pct": round(r["collide_pct"], 1),
            }
            for m, r in rows.items()
        },  # fmt: skip
        "ours_vs_nearest_neighbour_total": round(ours["total"] / nn["total"], 3),
        "ours_vs_nearest_neighbour_iou_loss": round(ours["iou_loss"] / nn["iou_loss"], 3),
        "unrefined_vs_nearest_neighbour_total": round(rows["Ours w/o refinement"]["total"] / nn["total"], 3),
        "ours_collide_pct": ours["collide_pct"],
        "ours_seconds_per_target": round(ours["seconds"], 2),
    }
    first = rows.get("Ours, first answer")
    if first is not None:
        summary["first_answer_seconds"] = round(first["seconds"], 3)
        summary["first_answer_vs_nearest_neighbour_total"] = round(first["total"] / nn["total"], 3)
    if args.paper:
        from studio.evaluate.table1 import to_markdown

        paper = evaluate(cli, args, Path(args.out) / "paper", "paper")
        p = paper["Ours"]
        both = [*rows.values(), p | {"method": "Ours, paper configuration"}]
        print("Both configurations:\n\n" + to_markdown(both))
        summary["paper_configuration"] = {
            "total": round(p["total"], 4), "iou_loss": round(p["iou_loss"], 4),
            "seconds_per_target": round(p["seconds"], 2), "collide_pct": p["collide_pct"],
            "unrefined_iou_loss": round(paper["Ours w/o refinement"]["iou_loss"], 4),
            "ours_vs_paper_total": round(ours["total"] / p["total"], 3),
        }  # fmt: skip
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
