#!/usr/bin/env python3
"""Import cycles between the files of a crate (DESIGN.md: files of one crate do not import each
other in a circle). Prints each cycle as a chain of files, with the paths each file names of
the next, and exits 1 if there is any.

    module_cycles.py [DIR ...]   (a crate, i.e. a directory with src/, or a directory of
                                  crates; default: crates)

A file depends on another when its code names an item of the other, the way rustc resolves
paths (edition 2018 on), in a `use` tree or in an expression or type: `crate::a::X`;
`super::x` (in `a/b.rs`, module `a::b`, that is `a::x`; in `a/mod.rs`, a sibling of `a`);
`self::x`; a child module (`mod child;` then `child::f()`); a name a `use` brought in
(`use super::avx512 as wide;` then `wide::f()`), or that a glob (`use super::*`) brings in.
`use` trees may be groups (`use crate::{a::X, b::{self, Y}}`). A name a module re-exports
(`pub use matcher::StereoMatcher;`) leads on to the file that defines it, so an item defined
in a parent's `mod.rs` or `lib.rs` is an edge to that file, and one it only re-exports is not.

Declaring a child (`mod child;`) is not using it, and neither is re-exporting its items (a
`pub use`, `pub(crate) use` ... is the module's interface): such a `use` is an edge only if
the file's own code names what it brings in (`pub use matcher::StereoMatcher;` and
`StereoMatcher::new(...)` in the same file). Comments, string literals and `#[cfg(test)]` items
(test modules) are left out. Not seen: macro invocations (`macro_rules!` scope by text), items
reached through a method or a trait without a path naming them, and what a file's code uses of
its own glob re-export (`pub use child::*`)."""
import bisect
import os
import re
import sys

IDENT = r'[A-Za-z_]\w*'
RAW_STRING = re.compile(r'b?r(#*)"')
CHAR = re.compile(r"'(\\(?:x[0-9a-fA-F]{2}|u\{[0-9a-fA-F]*\}|.)|[^\\'\n])'")
TEST_ITEM = re.compile(r'#\[cfg\(test\)\](\s*#\[[^\]]*\])*')
MAX_SHOWN = 50  # cycles printed per crate (all are counted)


def code_only(text):
    """`text` with comments and the insides of string and char literals blanked (newlines and
    offsets kept, so positions still give line numbers)."""
    out, i, n = list(text), 0, len(text)

    def blank(a, b):
        for k in range(a, b):
            if out[k] != '\n':
                out[k] = ' '

    while i < n:
        c = text[i]
        if text.startswith('//', i):
            j = text.find('\n', i)
            j = n if j < 0 else j
            blank(i, j)
            i = j
        elif text.startswith('/*', i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith('/*', j):
                    depth, j = depth + 1, j + 2
                elif text.startswith('*/', j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            blank(i, j)
            i = j
        elif (m := RAW_STRING.match(text, i)) and not (i and (text[i - 1].isalnum() or text[i - 1] == '_')):
            j = text.find('"' + m.group(1), m.end())
            j = n if j < 0 else j + 1 + len(m.group(1))
            blank(m.end(), j - 1 - len(m.group(1)))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == '\\' else 1
            blank(i + 1, j)
            i = j + 1
        elif c == "'" and (m := CHAR.match(text, i)):
            blank(i + 1, m.end() - 1)  # a char literal; a lifetime `'a` has no closing quote
            i = m.end()
        else:
            i += 1
    return ''.join(out)


def without_tests(code):
    """`code` with every `#[cfg(test)]` item (and its other attributes) blanked."""
    out = list(code)
    for m in TEST_ITEM.finditer(code):
        depth, j = 0, m.end()
        while j < len(code):
            c = code[j]
            if c in '([{':
                depth += 1
            elif c in ')]}':
                depth -= 1
                if depth == 0 and c == '}':
                    break
            elif c == ';' and depth == 0:
                break
            j += 1
        for k in range(m.start(), min(j + 1, len(code))):
            if out[k] != '\n':
                out[k] = ' '
    return ''.join(out)


def use_leaves(tree, prefix=()):
    """Each leaf of a use tree as (path segments, the name it brings in): `a::{b, c::d as e, f::*}`
    gives (a, b) b, (a, c, d) e, (a, f) *."""
    tree = ' '.join(tree.split())
    if tree.endswith('}'):
        head, body = tree[:-1].split('{', 1)
        base = prefix + tuple(s.strip() for s in head.split('::'))
        base = base[:-1] if base[-1] == '' else base  # `a::{...}` and `{...}` leave an empty end
        parts, depth, start = [], 0, 0
        for k, c in enumerate(body):
            depth += (c == '{') - (c == '}')
            if c == ',' and depth == 0:
                parts.append(body[start:k])
                start = k + 1
        parts.append(body[start:])
        for part in parts:
            if part.strip():
                yield from use_leaves(part, base)
        return
    path, _, alias = tree.partition(' as ')
    segs = prefix + tuple(s.strip() for s in path.split('::'))
    if segs[-1] == '*':
        yield segs[:-1], '*'
    elif segs[-1] == 'self':
        yield segs[:-1], alias.strip() or segs[-2]
    else:
        yield segs, alias.strip() or segs[-1]


TOKEN = re.compile(rf'''
    (?P<mod>\bmod\s+(?P<name>{IDENT})\s*(?P<end>[;{{]))
  | (?P<use>(?P<pub>\bpub\b(?:\s*\([^)]*\))?\s*)?\buse\s+(?P<tree>[^;]*);)
  | (?P<path>(?<![\w:])\$?{IDENT}(?:\s*::\s*{IDENT})+)
  | (?P<ident>(?<![\w:.$]){IDENT}\b(?!\s*:))
  | (?P<open>\{{) | (?P<close>\}})''', re.X)


class Crate:
    def __init__(self, src):
        self.files = {}     # module path (tuple) -> file that holds it
        self.children = {}  # module -> names of its child modules
        self.names = {}     # module -> {name: (path segments as written)} from its `use`s
        self.globs = {}     # module -> [path segments of each `use ...::*`]
        self.refs = []      # (module, file, line, path segments) of every path its code names
        for d, _, fs in os.walk(src):
            for f in sorted(fs):
                if f.endswith('.rs'):
                    rel = os.path.relpath(os.path.join(d, f), src)[:-3].split(os.sep)
                    if rel[-1] in ('lib', 'main', 'mod'):
                        rel = rel[:-1]
                    self.files[tuple(rel)] = os.path.join(d, f)
        for module, f in list(self.files.items()):
            self.scan(module, f)

    def scan(self, module, f):
        code = without_tests(code_only(open(f, encoding='utf-8').read()))
        if '#![cfg(test)]' in code:
            return
        line_starts = [0] + [m.end() for m in re.finditer('\n', code)]
        scopes, depth = [(module, 0)], 0  # inline `mod x { ... }` blocks open a scope
        reexports, used = [], set()
        for m in TOKEN.finditer(code):
            here = scopes[-1][0]
            line = bisect.bisect_right(line_starts, m.start())
            if m.group('mod'):
                child = here + (m.group('name'),)
                self.children.setdefault(here, set()).add(m.group('name'))
                if m.group('end') == '{':
                    depth += 1
                    self.files[child] = f
                    scopes.append((child, depth))
            elif m.group('use'):
                for segs, name in use_leaves(m.group('tree')):
                    if name == '*':
                        self.globs.setdefault(here, []).append(segs)
                    elif name != '_':
                        self.names.setdefault(here, {})[name] = segs
                    if m.group('pub') and name != '_':
                        # A re-export declares the module's interface; its own code uses the
                        # name only where the name appears in it.
                        reexports.append((here, name, line, segs))
                    else:
                        self.refs.append((here, f, line, segs))
            elif m.group('ident'):
                used.add((here, m.group('ident')))
            elif m.group('path'):
                segs = tuple(s.strip() for s in m.group('path').lstrip('$').split('::'))
                self.refs.append((here, f, line, segs))
            elif m.group('open'):
                depth += 1
            elif m.group('close'):
                if scopes[-1][1] == depth and len(scopes) > 1:
                    scopes.pop()
                depth -= 1
        self.refs += [(mod, f, line, segs) for mod, name, line, segs in reexports
                      if (mod, name) in used]

    def absolute(self, module, segs, seen=()):
        """The crate-absolute path of `segs` written in `module`, or None (another crate, a local
        variable's type, ...)."""
        if not segs or (module, segs) in seen:
            return None
        seen += ((module, segs),)
        head, rest = segs[0], segs[1:]
        if head == 'crate':
            return rest
        if head == 'self':
            return module + rest
        if head == 'super':
            while segs and segs[0] == 'super':
                module, segs = module[:-1], segs[1:]
            return module + segs
        if head in self.children.get(module, ()):
            return module + segs
        if head in self.names.get(module, {}):
            base = self.absolute(module, self.names[module][head], seen)
            return None if base is None else base + rest
        for glob in self.globs.get(module, []):
            source = self.absolute(module, glob, seen)
            if source is not None and (head in self.children.get(source, ())
                                       or head in self.names.get(source, {})):
                return self.absolute(source, segs, seen)
        return None

    def defining_file(self, path, seen=()):
        """The file that defines the item at crate-absolute `path`: the innermost module on the
        path, or, where that module only re-exports the next name, the re-exported item's file."""
        for n in range(len(path), -1, -1):
            module = path[:n]
            if module in self.files:
                if n < len(path) and path[n] in self.names.get(module, {}) and path not in seen:
                    target = self.absolute(module, self.names[module][path[n]])
                    if target is not None:
                        return self.defining_file(target + path[n + 1:], seen + (path,))
                return self.files[module]
        return None

    def edges(self):
        """{file: {file it depends on: {path as written: first line}}}"""
        out = {f: {} for f in set(self.files.values())}
        for module, f, line, segs in self.refs:
            path = self.absolute(module, segs)
            target = None if path is None else self.defining_file(path)
            if target and target != f:
                out[f].setdefault(target, {}).setdefault('::'.join(segs), line)
        return out


def reachable(edges, start):
    """The files `start` depends on, directly or not."""
    seen, todo = set(), [start]
    while todo:
        for nxt in edges[todo.pop()]:
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def cycles(edges):
    """Every elementary cycle, each once: from its smallest file, through larger ones (only
    through files that lead back to it)."""
    found, reaches = [], {f: reachable(edges, f) for f in edges}

    def walk(start, path):
        for nxt in sorted(edges[path[-1]]):
            if nxt == start:
                found.append(path + [start])
            elif nxt > start and nxt not in path and start in reaches[nxt]:
                walk(start, path + [nxt])

    for start in sorted(edges):
        walk(start, [start])
    return found


def crates(args):
    """(name, src) of each crate named: a directory with `src/`, or a directory of such."""
    for arg in args or ['crates']:
        if os.path.isdir(os.path.join(arg, 'src')):
            yield os.path.basename(os.path.normpath(arg)), os.path.join(arg, 'src')
        else:
            for name in sorted(os.listdir(arg)):
                if os.path.isdir(os.path.join(arg, name, 'src')):
                    yield name, os.path.join(arg, name, 'src')


def main():
    total = 0
    for name, src in crates(sys.argv[1:]):
        edges = Crate(src).edges()
        found = cycles(edges)
        total += len(found)
        for cycle in found[:MAX_SHOWN]:
            print(f'{name}: ' + ' -> '.join(cycle))
            for a, b in zip(cycle, cycle[1:]):
                names = sorted(edges[a][b].items(), key=lambda item: (item[1], item[0]))
                print(f'    {a} -> {b}: ' + ', '.join(f'{p} (line {n})' for p, n in names))
        if len(found) > MAX_SHOWN:
            print(f'{name}: ... and {len(found) - MAX_SHOWN} more cycles')
    print('cycles:', total)
    return 1 if total else 0


if __name__ == '__main__':
    sys.exit(main())
