#!/usr/bin/env python3
"""Compare two folders written by scripts/outputs_snapshot.sh (issue 40).

    scripts/outputs_compare.py BEFORE AFTER

Every file must be in both folders and equal:
- FITS files byte for byte, apart from the values of the DATE, CHECKSUM and DATASUM
  cards (the card is kept, its value blanked on both sides, so a card that moved or a
  keyword that changed still differs);
- everything else byte for byte, apart from wall-clock times in the text ("in 1.23 s",
  "12.3 ms", "elapsed": 0.5 in JSON, pixels or MB per second), which a rerun of the
  same binary changes too, and the snapshot folder's own absolute path (read as
  "<dir>").

Exit 0 when equal, 1 with the differing files listed (and the first differing line of
text files), 2 on bad arguments.
"""

import re
import sys
from pathlib import Path

CARD = 80
BLOCK = 2880
VOLATILE_CARDS = (b"DATE    ", b"CHECKSUM", b"DATASUM ")

# Wall-clock quantities: a number followed by a time or rate unit, and JSON fields whose
# name says they are a duration or a rate.
TIME_TEXT = re.compile(
    rb"\d+(?:\.\d+)?(?:e[-+]?\d+)?\s*(?:s|ms|us|\xc2\xb5s|min|frames/s|lines/s|pixels/s|Mpx/s|MB/s|GB/s|px/s)\b"
)
TIME_JSON = re.compile(
    rb'("[a-z_]*(?:seconds|_s|_ms|elapsed|per_s|rate|wall)[a-z_]*"\s*:\s*)-?\d+(?:\.\d+)?(?:e[-+]?\d+)?'
)


def fits_masked(data: bytes) -> bytes:
    """The file with the values of the volatile header cards blanked, in every HDU."""
    out = bytearray(data)
    pos = 0
    while pos + BLOCK <= len(out):
        # A header: cards until END, padded to a block.
        end = None
        p = pos
        while p + CARD <= len(out):
            key = bytes(out[p : p + 8])
            if key in VOLATILE_CARDS:
                out[p + 8 : p + CARD] = b" " * (CARD - 8)
            if key == b"END     ":
                end = p + CARD
                break
            p += CARD
        if end is None:
            break
        header = bytes(out[pos:end])
        data_start = pos + -(-(end - pos) // BLOCK) * BLOCK
        pos = data_start + -(-data_size(header) // BLOCK) * BLOCK
    return bytes(out)


def data_size(header: bytes) -> int:
    """Bytes of the data unit that follows a header (FITS 4.0, section 4.4.1)."""
    cards = {}
    for i in range(0, len(header), CARD):
        card = header[i : i + CARD]
        if card[8:10] == b"= ":
            value = card[10:].split(b"/")[0].strip()
            cards[card[:8].strip().decode("ascii", "replace")] = value
    try:
        naxis = int(cards.get("NAXIS", b"0"))
        bitpix = abs(int(cards.get("BITPIX", b"8")))
        if naxis == 0:
            return 0
        n = 1
        for k in range(1, naxis + 1):
            n *= int(cards[f"NAXIS{k}"])
        if cards.get("XTENSION", b"").strip(b"' ") == b"BINTABLE" or b"GROUPS" in cards:
            n += int(cards.get("PCOUNT", b"0"))
        return n * bitpix // 8
    except (KeyError, ValueError):
        return 0


def snapshot_root(folder: Path) -> bytes:
    """The absolute path the snapshot was written at (its .snapshot-root file)."""
    mark = folder / ".snapshot-root"
    path = mark.read_text().strip() if mark.is_file() else str(folder.resolve())
    return path.encode()


def text_masked(data: bytes, root: bytes) -> bytes:
    data = data.replace(root, b"<dir>")
    data = TIME_JSON.sub(rb"\1<time>", data)
    return TIME_TEXT.sub(b"<time>", data)


def masked(path: Path, root: bytes) -> bytes:
    data = path.read_bytes()
    if data.startswith(b"SIMPLE  ="):
        return fits_masked(data)
    if path.suffix in (".png", ".bin", ".mem", ".gz"):
        return data
    return text_masked(data, root)


def first_difference(a: bytes, b: bytes) -> str:
    if b"\0" in a[:4096] or b"\0" in b[:4096]:
        for i, (x, y) in enumerate(zip(a, b)):
            if x != y:
                return f"first differing byte at {i}"
        return f"lengths {len(a)} and {len(b)}"
    la, lb = a.splitlines(), b.splitlines()
    for i, (x, y) in enumerate(zip(la, lb)):
        if x != y:
            return (
                f"line {i + 1}:\n    - {x[:200].decode('utf-8', 'replace')}\n"
                f"    + {y[:200].decode('utf-8', 'replace')}"
            )
    return f"{len(la)} and {len(lb)} lines"


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        return 2
    before, after = Path(sys.argv[1]), Path(sys.argv[2])
    for d in (before, after):
        if not d.is_dir():
            print(f"{d}: not a folder", file=sys.stderr)
            return 2
    files_a = {p.relative_to(before) for p in before.rglob("*") if p.is_file() and p.name not in (".snapshot-root", ".dncal")}
    files_b = {p.relative_to(after) for p in after.rglob("*") if p.is_file() and p.name not in (".snapshot-root", ".dncal")}
    root_a, root_b = snapshot_root(before), snapshot_root(after)
    problems = []
    for rel in sorted(files_a - files_b):
        problems.append(f"only in {before}: {rel}")
    for rel in sorted(files_b - files_a):
        problems.append(f"only in {after}: {rel}")
    same = 0
    for rel in sorted(files_a & files_b):
        a, b = masked(before / rel, root_a), masked(after / rel, root_b)
        if a == b:
            same += 1
        else:
            problems.append(f"differs: {rel}: {first_difference(a, b)}")
    for p in problems:
        print(p)
    print(f"{same} files equal, {len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
