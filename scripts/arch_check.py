#!/usr/bin/env python3
"""The architecture checks of issue 40, over host-sim's sources (standard library only).

    python3 scripts/arch_check.py                  # report every count and where
    python3 scripts/arch_check.py --ratchet FILE   # fail when a count rises above FILE's
    python3 scripts/arch_check.py --write FILE     # record the counts as the new ratchet

Counts (each should reach 0; the ratchet keeps them from rising meanwhile):
  import_cycles      source files that import each other, directly or through other
                     files (the files of every strongly connected component of the
                     graph of `use crate::...`, `super::...` and `crate::x::y` paths)
  string_results     `Result<..., String>` outside clap value parsers (functions passed
                     to `value_parser`)
  label_paths        a label where a file should be: `HostError::Variant { path: "..." }`,
                     `HostError::io("...")`, `Path::new`/`PathBuf::from` of a literal
                     with a space (test modules apart)
  commands_imports   `commands::` paths in files outside src/commands and src/bin (the
                     library reaching up into the CLI)
  command_calls      references from a file of src/commands/ to another command's module
                     (the shared `progress` and `mod.rs` apart), one per pair: a
                     command's work belongs in the library, where both can call it
  room_imports       references from a file in one room of src/ to a room above it
                     (ROOMS, lowest first: infra, formats, model, analyses, checks, then
                     the CLI in commands/ and bin/); a room may use itself and the rooms
                     below it

A file is its module path: src/a/b.rs and src/a/b/mod.rs are `a::b`. A reference to
`crate::a::b::c` counts as one to the longest module prefix that exists (`a::b`).
"""

import argparse
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SRC = ROOT / "host-sim" / "src"
# The rooms of src/, lowest first (docs/architecture.md).
ROOMS = ["infra", "formats", "model", "analyses", "checks", "commands", "bin"]


def module_of(path: Path) -> tuple:
    rel = path.relative_to(SRC).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] in ("mod", "lib", "main"):
        parts = parts[:-1]
    return tuple(parts)


def strip_comments(text: str) -> str:
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    return "\n".join("" if line.lstrip().startswith("//") else re.sub(r"(?<![:\"])//.*$", "", line) for line in text.splitlines())


def references(module: tuple, text: str, modules: set) -> set:
    """The modules `text` (of `module`) refers to by path."""
    out = set()
    # crate:: paths, including inside `use crate::{a, b::c}` groups (first level only).
    for m in re.finditer(r"crate::((?:[a-z_][a-z0-9_]*::)*[a-z_][a-z0-9_]*)", text):
        out.add(longest(tuple(m.group(1).split("::")), modules))
    for m in re.finditer(r"use crate::\{([^}]*)\}", text, flags=re.S):
        for item in m.group(1).split(","):
            item = item.strip().split("::")
            if item and item[0]:
                out.add(longest(tuple(i.strip() for i in item if i.strip() and i.strip() != "self"), modules))
    # super:: paths, relative to the file's module (a mod.rs is its folder's module).
    for m in re.finditer(r"((?:super::)+)((?:[a-z_][a-z0-9_]*::)*[a-z_][a-z0-9_]*)?", text):
        ups = m.group(1).count("super::")
        base = module[: max(0, len(module) - ups)]
        rest = tuple(m.group(2).split("::")) if m.group(2) else ()
        out.add(longest(base + rest, modules))
    out.discard(None)
    out.discard(module)
    out.discard(())
    return out


def longest(path: tuple, modules: set):
    for n in range(len(path), 0, -1):
        if path[:n] in modules:
            return path[:n]
    return None


def strongly_connected(graph: dict) -> list:
    """Tarjan's algorithm, iterative."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            node, it = work[-1]
            advanced = False
            for nxt in it:
                if nxt not in graph:
                    continue
                if nxt not in index:
                    index[nxt] = low[nxt] = counter[0]
                    counter[0] += 1
                    stack.append(nxt)
                    on.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                    advanced = True
                    break
                if nxt in on:
                    low[node] = min(low[node], index[nxt])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == node:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def check() -> dict:
    files = sorted(SRC.rglob("*.rs"))
    modules = {module_of(f) for f in files}
    texts = {module_of(f): (f, strip_comments(f.read_text())) for f in files}
    graph = {m: references(m, t, modules) for m, (_, t) in texts.items()}
    graph_all = graph
    # A parent module declares its children (`mod x;`) and re-exports them: that is
    # not an import back. Only edges between modules neither of which contains the
    # other count.
    graph = {m: {r for r in refs if r[: len(m)] != m and m[: len(r)] != r} for m, refs in graph.items()}
    cycles = strongly_connected(graph)
    where = {"import_cycles": ["::".join(m) for comp in cycles for m in comp]}

    parsers = set()
    for _, (_, t) in texts.items():
        parsers.update(re.findall(r"value_parser\s*=\s*([A-Za-z_][A-Za-z0-9_:]*)", t))
    parsers = {p.split("::")[-1] for p in parsers}
    string_results, label_paths, commands_imports, room_imports, command_calls = [], [], [], [], []
    for m, (f, t) in texts.items():
        rel = f.relative_to(ROOT)
        if m[:1] == ("commands",) and len(m) >= 2:
            for r in sorted(graph_all[m]):
                if r[:1] == ("commands",) and len(r) >= 2 and r[1] not in ("progress",) and r[:2] != m[:2]:
                    command_calls.append(f"{rel} -> {'::'.join(r)}")
        if m[:1] and m[0] in ROOMS:
            rank = ROOMS.index(m[0])
            for r in sorted(graph_all[m]):
                if r[0] in ROOMS and ROOMS.index(r[0]) > rank and not (m[0] in ("commands", "bin") and r[0] in ("commands", "bin")):
                    room_imports.append(f"{rel} -> {'::'.join(r)}")
        # The signature up to its body or where-clause: `;` may appear inside it (`[usize; 3]`).
        for fm in re.finditer(r"fn\s+([a-z_][a-z0-9_]*)\b(?:(?!\bfn\b)[^{])*?->\s*Result<(?:(?!\bfn\b)[^{])*?,\s*String\s*>\s*(?:\{|where)", t, flags=re.S):
            if fm.group(1) not in parsers:
                string_results.append(f"{rel}:{t[: fm.start()].count(chr(10)) + 1} {fm.group(1)}")
        # A label where a path goes: a literal in a path field or in HostError::io, or a
        # path made from a literal with a space in it (files do not have one; "camera
        # config" does); test modules apart.
        body = strip_comments(re.split(r"#\[cfg\(test\)\]\s*(?:pub(?:\(crate\))?\s+)?mod\s", t)[0])
        for lm in re.finditer(r"HostError::[A-Za-z]+\s*\{\s*path:\s*\"([^\"]*)\"|HostError::io\(\s*\"([^\"]*)\"|(?:Path::new|PathBuf::from)\(\s*\"([^\"]* [^\"]*)\"", body):
            label = next(g for g in lm.groups() if g is not None)
            label_paths.append(f"{rel}:{t[: lm.start()].count(chr(10)) + 1} \"{label}\"")
        if m[:1] not in (("commands",), ("bin",)):
            for cm in re.finditer(r"\bcommands::", t):
                commands_imports.append(f"{rel}:{t[: cm.start()].count(chr(10)) + 1}")
    where.update(string_results=string_results, label_paths=label_paths, commands_imports=commands_imports, room_imports=room_imports, command_calls=command_calls)
    return where


def self_test() -> None:
    """The checks on a planted tree: one cycle, one String result, one label path, one
    library file reaching into the CLI, one room reaching into a room above it (and one
    reaching down, by `super::`, which is allowed); each found once, and nothing else."""
    import tempfile
    global SRC, ROOT
    saved = (SRC, ROOT)
    with tempfile.TemporaryDirectory() as tmp:
        ROOT = Path(tmp)
        SRC = ROOT / "host-sim" / "src"
        (SRC / "commands").mkdir(parents=True)
        (SRC / "lib.rs").write_text("pub mod a; pub mod b; pub mod c; pub mod commands; pub mod formats; pub mod analyses;\n")
        (SRC / "formats").mkdir()
        (SRC / "analyses").mkdir()
        (SRC / "formats" / "mod.rs").write_text("pub mod x;\n")
        (SRC / "formats" / "x.rs").write_text("use crate::analyses::y;\nuse crate::formats::z;\n")
        (SRC / "formats" / "z.rs").write_text("pub fn z() {}\n")
        (SRC / "analyses" / "mod.rs").write_text("pub mod y;\n")
        (SRC / "analyses" / "y.rs").write_text("use super::super::formats::z;\npub fn y() {}\n")
        (SRC / "a.rs").write_text("use crate::b::f;\npub fn g() -> Result<u8, String> { Ok(1) }\n// crate::c::h in a comment is no import\nfn h(x: [u8; 3]) -> Result<[u8; 3], String> { let u = \"http://x\"; Ok(x) }\n")
        (SRC / "b.rs").write_text("use crate::a::g;\npub fn f() { crate::commands::x(); let e = HostError::Format { path: \"label\".into(), message: String::new() }; }\n")
        (SRC / "c.rs").write_text("use super::a::g;\n#[arg(value_parser = parse_n)]\nfn parse_n(s: &str) -> Result<u8, String> { Ok(0) }\n#[arg(value_parser = Kind::parse)]\nfn parse(s: &str) -> Result<u8, String> { Ok(0) }\nfn e() { HostError::Config { path: \"default\".into(), source }; HostError::io(\"stdout\", e); f(Path::new(\"camera config\"), Path::new(\"t.bin\")); }\n#[cfg(test)]\nmod tests { fn t() { HostError::io(\"x\", e); } }\n")
        (SRC / "commands" / "mod.rs").write_text("pub mod p; pub mod q; pub mod progress;\npub fn x() { crate::commands::y(); }\npub fn y() {}\n")
        (SRC / "commands" / "p.rs").write_text("use crate::commands::progress::bar;\nuse crate::commands::q::Q;\nuse super::y;\n")
        (SRC / "commands" / "q.rs").write_text("pub struct Q;\n")
        (SRC / "commands" / "progress.rs").write_text("pub fn bar() {}\n")
        w = check()
        SRC, ROOT = saved
    want = {
        "import_cycles": ["a", "b"],
        "string_results": ["host-sim/src/a.rs:2 g", "host-sim/src/a.rs:4 h"],
        "label_paths": ['host-sim/src/b.rs:2 "label"', 'host-sim/src/c.rs:6 "default"', 'host-sim/src/c.rs:6 "stdout"', 'host-sim/src/c.rs:6 "camera config"'],
        "commands_imports": ["host-sim/src/b.rs:2"],
        "room_imports": ["host-sim/src/formats/x.rs -> analyses::y"],
        "command_calls": ["host-sim/src/commands/p.rs -> commands::q"],
    }
    assert w == want, f"self-test: {w} != {want}"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ratchet", type=Path, help="fail when a count exceeds this file's")
    p.add_argument("--write", type=Path, help="record the counts in this file")
    p.add_argument("--self-test", action="store_true", help="check the checks on a planted tree first")
    a = p.parse_args()
    if a.self_test:
        self_test()
    where = check()
    counts = {k: len(v) for k, v in where.items()}
    for k, v in where.items():
        print(f"{k}: {len(v)}")
        for line in v:
            print(f"  {line}")
    if a.write:
        a.write.write_text(json.dumps(counts, indent=2, sort_keys=True) + "\n")
        print(f"wrote {a.write}")
    if a.ratchet:
        limit = json.loads(a.ratchet.read_text())
        risen = [f"{k}: {counts[k]} > {limit.get(k, 0)}" for k in counts if counts[k] > limit.get(k, 0)]
        if risen:
            print("arch_check: counts rose above " + str(a.ratchet) + ": " + "; ".join(risen), file=sys.stderr)
            return 1
        fallen = [f"{k}: {counts[k]} < {limit[k]}" for k in counts if counts[k] < limit.get(k, 0)]
        if fallen:
            print("arch_check: counts fell (lower the ratchet with --write): " + "; ".join(fallen))
    return 0


if __name__ == "__main__":
    sys.exit(main())
