#!/usr/bin/env python3
"""Finds import circles between the files of each crate: file A `use crate::`s something defined in
file B while B, directly or through other files, uses something of A.

The module tree is followed from `src/lib.rs` (else `src/main.rs`) through `mod x;` declarations
(`x.rs` or `x/mod.rs` in the declaring module's folder). A `use crate::a::b::Item` resolves to the
file of the deepest module on the path; an item re-exported with `pub use` (the crate root's `pub use
render::Rendered`) resolves to the file that defines it, and the crate root's re-exports are not
themselves imports. Test code is left out: files declared under `#[cfg(test)]` and `#[cfg(test)] mod
name { ... }` blocks. With `--super`, `use super::`, `use self::` and `use child::` count too (a
child module that uses its parent's items while the parent uses the child's is then a circle).

Each strongly connected group of files is printed with the imports that tie it. Exit status 1 when
any crate has a circle, 0 otherwise.

    python3 scripts/check_module_cycles.py [--super] [crate folder ...]   (default: crates/*)
"""

import argparse
import pathlib
import re
import sys

MOD_DECL = re.compile(r"(#\[cfg\(test\)\]\s*)?(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;")
CFG_TEST_BLOCK = re.compile(r"#\[cfg\(test\)\]\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+\w+\s*\{")
USE = re.compile(r"\b(pub(?:\([^)]*\))?\s+)?use\s+([^;]*);")


def strip_comments_and_strings(src):
    """Source with comments, string and char literals blanked (newlines kept)."""
    out, i, n = [], 0, len(src)
    while i < n:
        c = src[i]
        if src.startswith("//", i):
            j = src.find("\n", i)
            i = n if j < 0 else j
        elif src.startswith("/*", i):
            depth, i = 1, i + 2
            while i < n and depth:
                if src.startswith("/*", i):
                    depth, i = depth + 1, i + 2
                elif src.startswith("*/", i):
                    depth, i = depth - 1, i + 2
                else:
                    out.append("\n" if src[i] == "\n" else "")
                    i += 1
        elif c == "r" and re.match(r'r#*"', src[i:i + 10]) and (i == 0 or not src[i - 1].isalnum()):
            hashes = re.match(r"r(#*)\"", src[i:]).group(1)
            end = src.find('"' + hashes, i + 2 + len(hashes))
            i = n if end < 0 else end + 1 + len(hashes)
            out.append('""')
        elif c == '"':
            i += 1
            while i < n and src[i] != '"':
                i += 2 if src[i] == "\\" else 1
            i += 1
            out.append('""')
        elif c == "'" and re.match(r"'(\\.|[^\\'])'", src[i:i + 4]) or src.startswith("'\\u{", i):
            i = src.find("'", i + 2) + 1
            out.append("' '")
        else:
            out.append(c)
            i += 1
    return "".join(out)


def drop_cfg_test_blocks(src):
    """Removes `#[cfg(test)] mod name { ... }` blocks (brace-matched)."""
    while True:
        m = CFG_TEST_BLOCK.search(src)
        if not m:
            return src
        depth, i = 1, m.end()
        while i < len(src) and depth:
            depth += {"{": 1, "}": -1}.get(src[i], 0)
            i += 1
        src = src[:m.start()] + src[i:]


def split_top(s):
    """Splits `s` at commas that are not inside braces."""
    parts, depth, cur = [], 0, ""
    for c in s:
        if c == "," and depth == 0:
            parts.append(cur)
            cur = ""
            continue
        depth += {"{": 1, "}": -1}.get(c, 0)
        cur += c
    parts.append(cur)
    return [p.strip() for p in parts if p.strip()]


def expand(tree, prefix=()):
    """`a::{b, c::{d, e as f}}` -> [(path, name bound)], `self` meaning the prefix itself."""
    tree = re.sub(r"\s+", "", re.sub(r"\s+as\s+", "=>", tree))
    if "{" in tree and tree.endswith("}"):
        head, body = tree.split("{", 1)
        head = tuple(s for s in head.split("::") if s)
        return [x for part in split_top(body[:-1]) for x in expand(part, prefix + head)]
    tree, _, alias = tree.partition("=>")
    segs = tuple(s for s in tree.split("::") if s)
    if segs == ("self",):
        return [(prefix, alias or (prefix[-1] if prefix else "self"))]
    return [(prefix + segs, alias or (segs[-1] if segs else ""))]


class Crate:
    def __init__(self, root_file):
        self.files = {}  # module path (tuple) -> (file, cleaned source)
        self.test_only = set()
        self._load(root_file, ())

    def _load(self, path, mod):
        src = strip_comments_and_strings(path.read_text())
        self.files[mod] = (path, drop_cfg_test_blocks(src))
        if path.name in ("lib.rs", "main.rs", "mod.rs"):
            folder = path.parent
        else:
            folder = path.parent / path.stem
        for m in MOD_DECL.finditer(src):
            child = mod + (m.group(2),)
            for cand in (folder / f"{m.group(2)}.rs", folder / m.group(2) / "mod.rs"):
                if cand.is_file():
                    self._load(cand, child)
                    if m.group(1) or mod in self.test_only:
                        self.test_only.add(child)
                    break

    def uses(self, mod, with_super):
        """(absolute path, text) of every `use` of module `mod` that names this crate."""
        src = self.files[mod][1]
        for m in USE.finditer(src):
            if mod == () and m.group(1):
                continue  # the crate root's re-exports are its public face, not code it uses
            for path, _ in expand(m.group(2)):
                if not path:
                    continue
                if path[0] == "crate":
                    yield path[1:], m.group(0)
                elif with_super and mod + (path[0],) in self.files:
                    yield mod + path, m.group(0)
                elif with_super and path[0] in ("self", "super"):
                    base = list(mod)
                    rest = list(path)
                    while rest and rest[0] in ("self", "super"):
                        if rest.pop(0) == "super":
                            base = base[:-1]
                    yield tuple(base) + tuple(rest), m.group(0)

    def reexports(self, mod):
        """name -> absolute path, and glob targets, of `pub use` in module `mod`."""
        named, globs = {}, []
        for m in USE.finditer(self.files[mod][1]):
            if not m.group(1):
                continue
            for path, name in expand(m.group(2)):
                if not path:
                    continue
                if path[0] == "crate":
                    absolute = path[1:]
                elif path[0] in ("self", "super") or mod + (path[0],) in self.files:
                    base, rest = list(mod), list(path)
                    while rest and rest[0] in ("self", "super"):
                        if rest.pop(0) == "super":
                            base = base[:-1]
                    absolute = tuple(base) + tuple(rest)
                else:
                    continue  # another crate
                if absolute[-1] == "*":
                    globs.append(absolute[:-1])
                else:
                    named[name] = absolute
        return named, globs

    def resolve(self, path, depth=0):
        """The module whose file defines what `path` names."""
        mod = ()
        for i, seg in enumerate(path):
            if mod + (seg,) in self.files:
                mod = mod + (seg,)
                continue
            if depth < 8:
                named, globs = self.reexports(mod)
                if seg in named and named[seg] != mod + (seg,):
                    return self.resolve(named[seg] + tuple(path[i + 1:]), depth + 1)
                for g in globs:
                    target = self.resolve(g + (seg,), depth + 1)
                    if target != g:
                        return target
            return mod
        return mod


def sccs(nodes, edges):
    """Tarjan's strongly connected components."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            out.append(comp)

    sys.setrecursionlimit(10000)
    for v in nodes:
        if v not in index:
            visit(v)
    return out


def check(crate_dir, with_super):
    src = crate_dir / "src"
    root = src / "lib.rs" if (src / "lib.rs").is_file() else src / "main.rs"
    if not root.is_file():
        return []
    crate = Crate(root)
    mods = [m for m in crate.files if m not in crate.test_only]
    edges, why = {}, {}
    for m in mods:
        for path, text in crate.uses(m, with_super):
            target = crate.resolve(path)
            if target == m or target in crate.test_only or target not in crate.files:
                continue
            edges.setdefault(m, set()).add(target)
            why.setdefault((m, target), set()).add(" ".join(text.split()))
    name = lambda m: str(crate.files[m][0].relative_to(crate_dir))
    found = []
    for comp in sccs(mods, edges):
        if len(comp) > 1:
            comp = sorted(comp, key=name)
            ties = [
                (name(a), name(b), sorted(why[(a, b)]))
                for a in comp
                for b in sorted(edges.get(a, ()), key=name)
                if b in comp
            ]
            found.append(([name(m) for m in comp], ties))
    return found


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("crates", nargs="*", type=pathlib.Path)
    ap.add_argument("--super", action="store_true", help="count `use super::/self::/child::` too")
    args = ap.parse_args()
    root = pathlib.Path(__file__).resolve().parent.parent
    crates = args.crates or sorted(p for p in (root / "crates").iterdir() if (p / "Cargo.toml").is_file())
    total = 0
    for c in crates:
        for files, ties in check(c, args.super):
            total += 1
            print(f"{c.name}: circle between {len(files)} files: {', '.join(files)}")
            for a, b, texts in ties:
                for t in texts:
                    print(f"    {a} -> {b}: {t}")
    print(f"{total} circle(s) found" if total else "no import circles between files")
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(main())
