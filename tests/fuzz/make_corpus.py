#!/usr/bin/python3
"""Write the libFuzzer seed corpora under tests/fuzz/corpus/<target>/ from the
frames of proto/vectors/vectors.json (valid and invalid alike).

    /usr/bin/python3 tests/fuzz/make_corpus.py

fuzz_pose_batch gets the POSE_BATCH, ACK, PING and PONG vectors as they are;
fuzz_contact the CONTACT vectors; fuzz_colliders the COLLIDERS vectors; fuzz_footprints the FOOTPRINTS vectors; fuzz_delta (whose input is a region byte
then length-prefixed frames, see fuzz_delta.c) each DELTA vector alone, and
each mirror scenario's frames in order with its own region. File names are
the vectors' names, so re-running after the vectors change rewrites the
corpus in place; the output is committed.
"""
import json
import os
import struct
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
VECTORS = os.path.join(ROOT, "proto", "vectors", "vectors.json")
OUT = os.path.join(ROOT, "tests", "fuzz", "corpus")

TARGETS = {
    "POSE_BATCH": "fuzz_pose_batch",
    "ACK": "fuzz_pose_batch",
    "PING": "fuzz_pose_batch",
    "PONG": "fuzz_pose_batch",
    "CONTACT": "fuzz_contact",
    "COLLIDERS": "fuzz_colliders",
    "FOOTPRINTS": "fuzz_footprints",
    "DELTA": "fuzz_delta",
}
# fuzz_delta.c's region table: (x, y, w, h, tile) -> selector byte
REGIONS = {(2, 2, 6, 5, 4): 0, (-5, -3, 4, 4, 4): 1}


def framed(frames):
    return b"".join(struct.pack("<I", len(f)) + f for f in frames)


def main():
    with open(VECTORS) as f:
        v = json.load(f)
    files = {}
    for vec in v["vectors"]:
        target = TARGETS[vec["type"]]
        frame = bytes.fromhex(vec["hex"])
        if target == "fuzz_delta":
            frame = bytes([0]) + framed([frame])
        files[(target, vec["name"])] = frame
    for sc in v["mirror_scenarios"]:
        r = sc["region"]
        sel = REGIONS.get((r["x"], r["y"], r["w"], r["h"], sc["tile_size"]))
        if sel is None:
            print(f"make_corpus: scenario {sc['name']}: region not in fuzz_delta.c's table, skipped",
                  file=sys.stderr)
            continue
        frames = [bytes.fromhex(s["frame_hex"]) for s in sc["steps"]]
        files[("fuzz_delta", "scenario_" + sc["name"])] = bytes([sel]) + framed(frames)
    for (target, name), data in sorted(files.items()):
        d = os.path.join(OUT, target)
        os.makedirs(d, exist_ok=True)
        with open(os.path.join(d, name), "wb") as f:
            f.write(data)
    counts = {}
    for target, _ in files:
        counts[target] = counts.get(target, 0) + 1
    print("make_corpus: " + ", ".join(f"{t}: {n} seeds" for t, n in sorted(counts.items())))


if __name__ == "__main__":
    main()
