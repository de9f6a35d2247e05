#!/usr/bin/env python3
"""Import cycles between the files of each crate (DESIGN.md: files of one crate do not import each
other in a circle). A file depends on another when its code (not its comments or tests) names a
module path of it: `crate::a::b`, `super::x`, `self::y`. Prints each cycle; exits 1 if any.
   module_cycles.py [CRATES_DIR]"""
import os, re, sys
root = sys.argv[1] if len(sys.argv) > 1 else 'crates'
def modpath(crate_src, f):
    rel = os.path.relpath(f, crate_src)[:-3].split(os.sep)
    if rel[-1] in ('lib', 'main'): rel = rel[:-1]
    elif rel[-1] == 'mod': rel = rel[:-1]
    return rel
cycles_found = 0
for crate in sorted(os.listdir(root)):
    src = os.path.join(root, crate, 'src')
    if not os.path.isdir(src): continue
    files = [os.path.join(d, f) for d, _, fs in os.walk(src) for f in fs if f.endswith('.rs')]
    mods = {tuple(modpath(src, f)): f for f in files}
    def resolve(path):
        # the longest prefix of path that is a module file
        for n in range(len(path), 0, -1):
            if tuple(path[:n]) in mods: return tuple(path[:n])
        return None
    edges = {m: set() for m in mods}
    for m, f in mods.items():
        text = open(f).read()
        # strip test modules
        text = re.split(r'#\[cfg\(test\)\]\s*mod tests', text)[0]
        text = '\n'.join(l for l in text.split('\n') if not l.lstrip().startswith('//'))
        is_mod = f.endswith('mod.rs') or f.endswith('lib.rs')
        here = list(m)
        parent = here if is_mod else here[:-1]
        for mm in re.finditer(r'\b(crate|super|self)((?:::\w+)+)', text):
            kind, rest = mm.group(1), mm.group(2).split('::')[1:]
            if kind == 'crate': base = []
            elif kind == 'super': base = (here[:-1] if is_mod else here[:-1])[:-1] if not is_mod else here[:-1]
            else: base = here if is_mod else here[:-1]
            if kind == 'super' and not is_mod: base = here[:-2] if len(here) >= 2 else []
            target = resolve(base + rest)
            if target and target != m and not (len(target) < len(m) and tuple(m[:len(target)]) == target and False):
                # ignore edges to one's own ancestors (a parent's re-exports are the normal way down)
                if tuple(m[:len(target)]) == target: continue
                edges[m].add(target)
    # find cycles (Tarjan SCC)
    index, low, stack, on, sccs, i = {}, {}, [], set(), [], [0]
    def strong(v):
        index[v] = low[v] = i[0]; i[0] += 1; stack.append(v); on.add(v)
        for w in edges[v]:
            if w not in index: strong(w); low[v] = min(low[v], low[w])
            elif w in on: low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop(); on.discard(w); comp.append(w)
                if w == v: break
            if len(comp) > 1: sccs.append(comp)
    sys.setrecursionlimit(10000)
    for v in edges:
        if v not in index: strong(v)
    for c in sccs:
        cycles_found += 1
        print(crate, ':', ' ↔ '.join('::'.join(x) or 'lib' for x in c))
print('cycles:', cycles_found)
sys.exit(1 if cycles_found else 0)
