#!/usr/bin/env python3
"""scalpel beside its peers on the B5 cantilever: error against run time in one run.

Creates the peers' venv (target/peers-venv, from requirements.txt) if it is missing, then for
each node count runs scalpel (`scalpel bench accuracy`, explicit and projective), MuJoCo flex
and Warp's XPBD FEM on the same cantilever, interleaved and pinned to the same core, so the
ratios come from one run on one core however busy the machine is. Writes into --out:

  peers.json   every run, and the medians the plot takes (`scalpel bench accuracy --peers`)
  peers.md     the table: nodes, peer, ms per simulated ms, error vs the 3D reference,
               scalpel (explicit) / peer
  accuracy.png the error-against-run-time plot with scalpel's modes and the peers

Usage (from the repository root, after `cargo build --release`):
  python3 tools/bench/peers/run.py --out target/peers            # full: 3..9 across, 3 runs
  python3 tools/bench/peers/run.py --out target/peers --short    # CI: 3 across, 1 run
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
HERE = Path(__file__).resolve().parent
VENV = ROOT / "target" / "peers-venv"
SCALPEL = ROOT / "target" / "release" / "scalpel"
REFERENCE = json.loads((ROOT / "tools" / "reference" / "reference.json").read_text())
REFERENCE_TIP_M = REFERENCE["cantilever"]["tip_m"]

PEERS = {
    "mujoco-flex": "mujoco_cantilever.py",
    "xpbd-warp": "xpbd_cantilever.py",
}


def log(line):
    print(line, file=sys.stderr, flush=True)


def ensure_venv():
    """The peers' venv with requirements.txt installed; pip runs only when the file changed
    since the last install (a stamp in the venv holds the file's text)."""
    python = VENV / "bin" / "python"
    if not python.exists():
        log(f"creating {VENV}")
        subprocess.run([sys.executable, "-m", "venv", str(VENV)], check=True)
    requirements = (HERE / "requirements.txt").read_text()
    stamp = VENV / "scalpel-peers-requirements.txt"
    if not stamp.exists() or stamp.read_text() != requirements:
        subprocess.run(
            [str(python), "-m", "pip", "install", "-q", "-r", str(HERE / "requirements.txt")],
            check=True,
        )
        stamp.write_text(requirements)
    return python


def on_core(core):
    """A child's pre-exec hook: pin it to `core`, as this process is."""
    return lambda: os.sched_setaffinity(0, {core})


def run_json(command, core):
    out = subprocess.run(
        command, check=True, capture_output=True, text=True, preexec_fn=on_core(core)
    )
    return json.loads(out.stdout)


def scalpel_run(across, mode, core, scratch):
    report = run_json(
        [
            str(SCALPEL), "bench", "accuracy", "--out", str(scratch),
            "--min-across", str(across), "--max-across", str(across),
            "--case", "cantilever", "--mode", mode, "--json",
        ],
        core,
    )
    row = report["rows"][0]
    return {
        "peer": f"scalpel-{mode}",
        "across": across,
        "nodes": row["points"],
        "wall_s_per_simulated_s": row["wall_s_per_simulated_s"],
        "tip_m": row["tip_m"],
        "error": row["error"],
    }


def peer_run(python, name, across, core):
    r = run_json([str(python), str(HERE / PEERS[name]), "--across", str(across), "--json"], core)
    return {
        "peer": name,
        "across": across,
        "nodes": r["nodes"],
        "wall_s_per_simulated_s": r["wall_s_per_simulated_s"],
        "tip_m": r["tip_m"],
        "error": abs(r["tip_m"] / REFERENCE_TIP_M - 1.0),
        "timestep_s": r.get("timestep_s"),
        # Warp's XPBD wanders by 0.1-0.5 % in float32 round-off, so it never reads as settled
        # (README.md); kept for the record, not enforced.
        "settled": r.get("settled"),
    }


def medians(runs):
    """One row per (peer, across): the median cost over the repeats (the answer is the
    same in every repeat), and the median over the repeats of scalpel explicit's cost over
    this one's in the same repeat (a ratio within one run, not a ratio of medians)."""
    keyed = {}
    for r in runs:
        keyed.setdefault((r["peer"], r["across"]), []).append(r)
    rows = []
    for (peer, across), group in sorted(keyed.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        ours = keyed[("scalpel-explicit", across)]
        row = dict(group[0])
        row["wall_s_per_simulated_s"] = statistics.median(
            g["wall_s_per_simulated_s"] for g in group
        )
        row["scalpel_over_this"] = statistics.median(
            o["wall_s_per_simulated_s"] / g["wall_s_per_simulated_s"]
            for o, g in zip(ours, group)
        )
        row["runs"] = len(group)
        rows.append(row)
    return rows


def table(rows):
    lines = [
        "| points across | nodes | simulator | ms per simulated ms | error vs 3D reference | "
        "scalpel explicit / this |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['across']} | {r['nodes']} | {r['peer']} | {r['wall_s_per_simulated_s']:.3f} | "
            f"{100 * r['error']:.1f} % | {r['scalpel_over_this']:.3f} |"
        )
    return "\n".join(lines) + "\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--short", action="store_true", help="3 across, one run (CI)")
    parser.add_argument("--core", type=int, default=None, help="the core to pin to")
    args = parser.parse_args()
    if not SCALPEL.exists():
        sys.exit(f"{SCALPEL} is missing: run `cargo build --release` first")
    python = ensure_venv()
    core = args.core if args.core is not None else max(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})
    args.out.mkdir(parents=True, exist_ok=True)
    scratch = args.out / "scalpel-runs"
    across_list = [3] if args.short else [3, 5, 7, 9]
    repeats = 1 if args.short else 3
    runs = []
    for repeat in range(repeats):
        for across in across_list:
            for mode in ["explicit", "projective"]:
                runs.append(scalpel_run(across, mode, core, scratch))
            for name in PEERS:
                runs.append(peer_run(python, name, across, core))
            for r in runs[-4:]:
                log(
                    f"run {repeat + 1}/{repeats}, {across} across: {r['peer']:<19} "
                    f"{r['wall_s_per_simulated_s']:8.3f} s per simulated s, "
                    f"error {100 * r['error']:5.1f} %"
                )
    rows = medians(runs)
    (args.out / "peers.json").write_text(
        json.dumps(
            {"core": core, "reference_tip_m": REFERENCE_TIP_M, "rows": rows, "runs": runs},
            indent=2,
        )
        + "\n"
    )
    (args.out / "peers.md").write_text(table(rows))
    print(table(rows))
    # The plot: scalpel's whole sweep (both modes, cantilever and uniaxial) with the peers'
    # medians (scalpel's own rows in the peers file are left out: the sweep has them).
    peers_only = {"rows": [r for r in rows if not r["peer"].startswith("scalpel-")]}
    (args.out / "peers-plot.json").write_text(json.dumps(peers_only, indent=2) + "\n")
    sweep = ["--min-across", "3", "--max-across", "9"]
    if args.short:
        # The smallest sweep, with a cut series too small to mean much but quick.
        sweep = ["--min-across", "3", "--max-across", "3", "--cut-points", "600",
                 "--cut-reference", "1200"]
    subprocess.run(
        [str(SCALPEL), "bench", "accuracy", "--out", str(args.out), *sweep,
         "--peers", str(args.out / "peers-plot.json")],
        check=True,
        preexec_fn=on_core(core),
    )


if __name__ == "__main__":
    main()
