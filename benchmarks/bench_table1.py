"""Table 1 on the 26 ASL letters (one image per letter) with the shipped models, without CLIP.

A thin wrapper around ``shadow-studio evaluate``: collects the Random/Nearest Neighbour training shards first when
they are missing (``collect --resolution 128 --n 50000 --out data/sx128``), runs the evaluation, and prints a JSON
object as the last line with each method's mean Total, ours against Nearest Neighbour and Random (ratios measured
in the same run; below 1 means ours is better), the share of refined poses in collision and seconds per target.

    python benchmarks/bench_table1.py [--targets DIR] [--per-folder 1] [--out runs/table1] [-- extra evaluate args]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ASL = ROOT.parent / "shared" / "targets" / "asl"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--targets", default=str(ASL), help="target folder (default ../shared/targets/asl)")
    parser.add_argument("--per-folder", default="1", help="images per sub-folder (default 1: one per letter)")
    parser.add_argument("--data", default=str(ROOT / "data" / "sx128"), help="training shards (made when missing)")
    parser.add_argument("--out", default=str(ROOT / "runs" / "table1"), help="folder for the table files")
    parser.add_argument("extra", nargs="*", help="more `shadow-studio evaluate` options, after --")
    args = parser.parse_args()
    cli = [sys.executable, "-m", "studio.cli.main"]
    if not Path(args.data).is_dir():
        collect = [*cli, "collect", "--resolution", "128", "--n", "50000", "--out", args.data, "--quiet"]
        subprocess.run(collect, check=True, cwd=ROOT)
    cmd = [*cli, "evaluate", args.targets, "--per-folder", args.per_folder, "--out", args.out,
           "--nn-data", args.data, "--no-clip", "--quiet", *args.extra]  # fmt: skip
    done = subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.PIPE, text=True)
    rows = {r["method"]: r for r in json.loads(done.stdout.strip().splitlines()[-1])["rows"]}
    ours, nn, rnd = rows["Ours"], rows["Nearest Neighbour"], rows["Random"]
    print(Path(args.out, "table1.md").read_text())
    summary = {
        "targets": ours["targets"],
        **{f"total_{k.lower().replace(' ', '_').replace('/', '')}": round(r["total"], 4) for k, r in rows.items()},
        "ours_vs_nearest_neighbour": round(ours["total"] / nn["total"], 3),
        "ours_vs_random": round(ours["total"] / rnd["total"], 3),
        "ours_collide_pct": ours["collide_pct"],
        "unrefined_collide_pct": round(rows["Ours w/o refinement"]["collide_pct"], 1),
        "ours_seconds_per_target": round(ours["seconds"], 1),
    }
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
