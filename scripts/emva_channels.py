#!/usr/bin/env python3
"""Split an EMVA 1288 set into the sets of its colour channels.

EMVA 1288 characterizes a colour camera's channels apart: each channel is the
image of its own pixels, measured as a monochrome camera's. This writes, for
each cell (r, c) of a pattern of period P, a set of its own:

  OUT/r<r>c<c>/EMVA1288descriptor.txt   the same records, `n bits W' H'`
  OUT/r<r>c<c>/images/<name>.png        every frame's pixels at rows r, r+P, ...
                                        and columns c, c+P, ... (PNG of the
                                        frame's own mode: 8-bit 'L', 16-bit 'I;16')

and prints the descriptors' paths, one a line, row-major. The reference
implementation (scripts/emva_reference.py) run on each is an oracle for
`dncal emva`'s `channels` that dncal did not write: the same standard applied
to the subsampled images, as the standard says a colour camera is measured.

Usage: emva_channels.py DESCRIPTOR --period P --out DIR
Needs numpy and Pillow (the emva1288 venv, scripts/emva-venv.sh, has both).
"""
import argparse
import os
import sys

import numpy as np
from PIL import Image


def main(argv):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("descriptor")
    p.add_argument("--period", type=int, required=True)
    p.add_argument("--out", required=True)
    a = p.parse_args(argv)
    if a.period < 1:
        sys.exit("emva_channels: --period must be at least 1")
    base = os.path.dirname(os.path.abspath(a.descriptor))
    with open(a.descriptor) as f:
        lines = f.read().splitlines()
    P = a.period
    written = []
    for r in range(P):
        for c in range(P):
            out = os.path.join(os.path.abspath(a.out), "r%dc%d" % (r, c))
            os.makedirs(out, exist_ok=True)
            text = []
            for line in lines:
                fields = line.split()
                if fields and fields[0] == "n":
                    bits, w, h = int(fields[1]), int(fields[2]), int(fields[3])
                    text.append("n %d %d %d" % (bits, len(range(c, w, P)), len(range(r, h, P))))
                elif fields and fields[0] == "i":
                    rel = line.split(None, 1)[1].strip()
                    src = os.path.join(base, *rel.replace("\\", "/").split("/"))
                    dst = os.path.join(out, *rel.replace("\\", "/").split("/"))
                    os.makedirs(os.path.dirname(dst), exist_ok=True)
                    with Image.open(src) as im:
                        mode = im.mode
                        arr = np.asarray(im)
                    sub = np.ascontiguousarray(arr[r::P, c::P])
                    if mode == "L":
                        Image.fromarray(sub.astype(np.uint8), "L").save(dst)
                    else:
                        Image.fromarray(sub.astype(np.uint16)).save(dst)
                    text.append(line)
                else:
                    text.append(line)
            path = os.path.join(out, os.path.basename(a.descriptor))
            with open(path, "w") as f:
                f.write("\n".join(text) + "\n")
            written.append(path)
    for path in written:
        print(path)


if __name__ == "__main__":
    main(sys.argv[1:])
