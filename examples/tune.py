"""The same tuning search for every learned imager, scored on validation data only (examples/PROTOCOL.md).

    python examples/tune.py run --model global --space examples/tuning/space.toml \
        --train split/train.npz --val split/val.npz --work work/tune/global \
        --log results/tuning/global.jsonl -o configs/global.toml
    python examples/tune.py args configs/global.toml pretrain      # the chosen arguments, for a Makefile

A space file lists the trials (each a set of `less pretrain` and `less image fit` arguments) that every
model runs, the arguments common to all, each model's own fixed arguments, and the test-time turns to try.
Every trial pretrains with validation stopping, fits the 3D image decoder (its labelling chosen on the same
validation scans), predicts the validation scans with each number of turns and scores them with `less
metrics`. The best validation 3D micro F1 wins (ties: the smaller centroid error). Each trial's record goes
to the search log as it finishes; the chosen arguments go to a config file the headline run reads.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import subprocess
import sys
import time
import tomllib
from pathlib import Path

SCORE, TIE = "f1_micro_3d", "com_error_mm_3d"


def read_space(path: str, model: str) -> dict:
    """The space file's trials for ``model``: each with pretrain / fit argument lists (common, own, trial)."""
    space = tomllib.loads(Path(path).read_text())
    common, own = space.get("common", {}), space.get("models", {}).get(model, {})
    if not space.get("trial"):
        raise SystemExit(f"{path}: no [[trial]] tables")
    trials = [{"trial": i,
               "pretrain": [*common.get("pretrain", []), *own.get("pretrain", []), *t.get("pretrain", [])],
               "fit": [*common.get("fit", []), *own.get("fit", []), *t.get("fit", [])]}
              for i, t in enumerate(space["trial"])]
    return {"trials": trials, "turns": [int(v) for v in common.get("turns", [1])]}


def less(cmd: list[str], args: argparse.Namespace) -> dict:
    """Run one `less` command; its last JSON record."""
    full = [*shlex.split(args.less), *cmd, "--device", args.device, "--threads", str(args.threads),
            "--format", "jsonl"]
    proc = subprocess.run(full, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise SystemExit(f"tune: {' '.join(full)} failed: {last}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def val_scores(pred: str, args: argparse.Namespace) -> dict:
    """Summary metrics of a prediction file (``less metrics --summary-only``)."""
    proc = subprocess.run([*shlex.split(args.less), "metrics", pred, "--summary-only", "--format", "jsonl"],
                          capture_output=True, text=True, check=True)
    row = json.loads(proc.stdout.strip().splitlines()[0])
    return {k: row.get(k) for k in (SCORE, TIE, "f1_micro_2d", "com_error_mm_2d")}


def pretrained(trial: dict, trials: list[dict], args: argparse.Namespace) -> tuple[Path, dict]:
    """The trial's representation and its `less pretrain` record. Trials with the same pretrain arguments
    share one (named after the first of them), trained once: a rerun reuses it when its arguments match."""
    first = next(t["trial"] for t in trials if t["pretrain"] == trial["pretrain"])
    rep = Path(args.work) / f"rep_t{first}.pt"
    meta = rep.with_suffix(".json")
    if rep.exists() and meta.exists():
        saved = json.loads(meta.read_text())
        if saved["pretrain"] == trial["pretrain"] and saved["seed"] == args.seed:
            return rep, saved
    t0 = time.perf_counter()
    ssl = less(["pretrain", args.train, "--val", args.val, "-o", str(rep), "--model", args.model,
                "--seed", str(args.seed), *trial["pretrain"]], args)
    saved = {"pretrain": trial["pretrain"], "seed": args.seed, "record": ssl,
             "seconds": round(time.perf_counter() - t0, 1)}
    meta.write_text(json.dumps(saved))
    return rep, saved


def run_trial(trial: dict, trials: list[dict], turns: list[int], args: argparse.Namespace) -> dict:
    work = Path(args.work)
    rep, ssl = pretrained(trial, trials, args)
    img = work / f"img_t{trial['trial']}.pt"
    t0 = time.perf_counter()
    fit = less(["image", "fit", args.train, "--val", args.val, "--rep", str(rep), "-o", str(img), "--dim",
                "3", "--seed", str(args.seed), *trial["fit"]], args)
    fit_seconds = round(time.perf_counter() - t0, 1)
    # train_seconds: what the trial's model costs to train from nothing (its self-supervision counted in
    # full even where another trial shares it)
    record = {**trial, "model": args.model, "ssl_best_loss": ssl["record"].get("best_loss"),
              "ssl_best_epoch": ssl["record"].get("best_epoch"), "fit_best_epoch": fit.get("best_epoch"),
              "labelling": {k: fit.get(k) for k in ("threshold", "min_volume_mm3", "smooth_mm")},
              "ssl_seconds": ssl["seconds"], "fit_seconds": fit_seconds,
              "train_seconds": round(ssl["seconds"] + fit_seconds, 1), "val": {}}
    for k in turns:
        pred = work / f"pred_t{trial['trial']}_turns{k}.npz"
        less(["image", "predict", str(img), args.val, "-o", str(pred), "--turns", str(k)], args)
        record["val"][str(k)] = val_scores(str(pred), args)
    return record


def rank_key(scores: dict) -> tuple[float, float]:
    """Higher F1 first, then the smaller centroid error; a missing score ranks last."""
    f1, com = scores.get(SCORE), scores.get(TIE)
    return (-(f1 if f1 is not None and math.isfinite(f1) else -1.0),
            com if com is not None and math.isfinite(com) else math.inf)


def choose(records: list[dict]) -> tuple[dict, int]:
    """The (trial, turns) with the best validation score."""
    cands = [(rank_key(r["val"][k]), r["trial"], int(k), r) for r in records for k in r["val"]]
    _, _, turns, best = min(cands, key=lambda c: (c[0], c[1], c[2]))
    return best, turns


def write_config(path: str, best: dict, turns: int, args: argparse.Namespace) -> None:
    scores = best["val"][str(turns)]
    lines = [(f"# {args.model}: chosen by examples/tune.py on {args.val} (validation only), trial "
              f"{best['trial']}"),
             f"# of {args.space}; search log: {args.log}",
             f'model = "{args.model}"', f"trial = {best['trial']}", f"turns = {turns}",
             f"pretrain = {json.dumps(best['pretrain'])}", f"fit = {json.dumps(best['fit'])}",
             f"val_{SCORE} = {scores[SCORE]}", f"val_{TIE} = {scores[TIE]}"]
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".part")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(out)


def cmd_run(args: argparse.Namespace) -> None:
    space = read_space(args.space, args.model)
    Path(args.work).mkdir(parents=True, exist_ok=True)
    Path(args.log).parent.mkdir(parents=True, exist_ok=True)
    done = {}
    if Path(args.log).exists():                      # a rerun continues the search where it stopped
        done = {r["trial"]: r for r in map(json.loads, Path(args.log).read_text().splitlines())
                if r["trial"] < len(space["trials"])
                and all(r.get(k) == space["trials"][r["trial"]][k] for k in ("pretrain", "fit"))}
    records = []
    for trial in space["trials"]:
        if trial["trial"] in done:
            records.append(done[trial["trial"]])
            continue
        record = run_trial(trial, space["trials"], space["turns"], args)
        records.append(record)
        with open(args.log, "a") as log:
            log.write(json.dumps(record) + "\n")
        print(json.dumps({"model": args.model, "trial": record["trial"], "val": record["val"],
                          "train_seconds": record["train_seconds"]}), file=sys.stderr)
    best, turns = choose(records)
    write_config(args.output, best, turns, args)
    print(json.dumps({"model": args.model, "trial": best["trial"], "turns": turns,
                      **best["val"][str(turns)]}))


def cmd_args(args: argparse.Namespace) -> None:
    config = tomllib.loads(Path(args.config).read_text())
    value = config[args.key]
    print(" ".join(shlex.quote(v) for v in value) if isinstance(value, list) else value)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run the search for one model and write its config")
    for name in ("--model", "--space", "--train", "--val", "--work", "--log"):
        run.add_argument(name, required=True)
    run.add_argument("-o", "--output", required=True, help="config file (TOML) of the chosen settings")
    run.add_argument("--seed", type=int, default=0)
    run.add_argument("--device", default="cpu")
    run.add_argument("--threads", type=int, default=1)
    run.add_argument("--less", default="less", help="the less command (default: less on PATH)")
    run.set_defaults(func=cmd_run)
    get = sub.add_parser("args", help="print one entry of a config file (arguments shell-quoted)")
    get.add_argument("config")
    get.add_argument("key", choices=("pretrain", "fit", "turns", "trial"))
    get.set_defaults(func=cmd_args)
    args = parser.parse_args(argv)
    args.func(args)


if __name__ == "__main__":
    main()
