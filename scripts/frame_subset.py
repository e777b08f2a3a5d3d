#!/usr/bin/env python3
"""Write a dataset of a few of another dataset's training frames, each also held out
as test_same, to ask how well the engine fits those frames together.

One frame alone has no other frame to disagree with; a run on it scores what the
field, sampler and optimiser can reach. Frames added one clip-span at a time then say
how much the frames' fits disagree (docs/results.md, "Frames that disagree").

    python3 scripts/frame_subset.py --data D --out D1 --first 40 --count 1
    talkin train --data D1 --out RUN --steps 1000
    talkin eval --run RUN --data D1 --split test_same --json E

The images and masks are symbolic links into D (nothing is copied); `import.json` is
copied, so that `train` applies the capture recipe as it does to D.
"""
import argparse
import copy
import json
import os
import shutil
import sys


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="the source dataset directory")
    ap.add_argument("--out", required=True, help="the dataset directory to create (absent or empty)")
    ap.add_argument("--first", type=int, required=True, help="index of the first training frame kept (0-based, among the train split)")
    ap.add_argument("--count", type=int, required=True, help="how many consecutive training frames to keep")
    args = ap.parse_args()

    src = os.path.abspath(args.data)
    manifest = os.path.join(src, "dataset.json")
    try:
        with open(manifest) as f:
            dataset = json.load(f)
        frames = dataset["frames"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        print(f"error: {manifest}: cannot read its 'frames' list: {e}", file=sys.stderr)
        return 2
    train = [f for f in frames if isinstance(f, dict) and f.get("split") == "train"]
    if args.count < 1 or args.first < 0 or args.first + args.count > len(train):
        print(
            f"error: {manifest}: --first {args.first} --count {args.count} needs training "
            f"frames {args.first}..{args.first + args.count - 1}; it has {len(train)}",
            file=sys.stderr,
        )
        return 2
    if os.path.exists(args.out) and os.listdir(args.out):
        print(f"error: {args.out} exists and is not empty", file=sys.stderr)
        return 2

    kept = []
    for frame in train[args.first : args.first + args.count]:
        kept.append(frame)
        held = copy.deepcopy(frame)
        held["split"] = "test_same"
        kept.append(held)
    subset = dict(dataset, frames=kept)

    os.makedirs(args.out, exist_ok=True)
    for name in sorted({os.path.dirname(f[k]) for f in kept for k in ("image", "mask") if f.get(k)}):
        if name:
            os.symlink(os.path.join(src, name), os.path.join(args.out, name))
    if os.path.exists(os.path.join(src, "import.json")):
        shutil.copy(os.path.join(src, "import.json"), args.out)
    tmp = os.path.join(args.out, "dataset.json.tmp")
    with open(tmp, "w") as f:
        json.dump(subset, f)
    os.replace(tmp, os.path.join(args.out, "dataset.json"))
    print(" ".join(f["image"] for f in kept if f["split"] == "train"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
