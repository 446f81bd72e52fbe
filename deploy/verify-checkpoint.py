#!/usr/bin/env python3
"""Checks checkpoint directories against their manifest.json (every file's size and
sha256), as `learner serve --resume` does, for the scripts that move runs
(deploy/pack-run.sh, deploy/unpack-run.sh). Prints `STEP (why)` for each one that
does not match and exits 1 if any does not.

Usage: deploy/verify-checkpoint.py CHECKPOINT_DIR...
"""
import hashlib
import json
import os
import sys


def problem(d):
    """Why checkpoint directory `d` does not match its manifest, or None."""
    try:
        with open(os.path.join(d, "manifest.json")) as fh:
            files = json.load(fh)["files"]
        for f in files:
            path = os.path.join(d, f["name"])
            if os.path.getsize(path) != f["size"]:
                return f"{f['name']}: size"
            h = hashlib.sha256()
            with open(path, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    h.update(block)
            if h.hexdigest() != f["sha256"]:
                return f"{f['name']}: sha256"
    except (OSError, ValueError, KeyError, TypeError) as e:
        return str(e)
    return None


bad = 0
for d in sys.argv[1:]:
    why = problem(d)
    if why is not None:
        print(f"{os.path.basename(os.path.normpath(d))} ({why})")
        bad += 1
sys.exit(1 if bad else 0)
