#!/usr/bin/env python3
"""The test of module_cycles.py: runs it on each fake crate of fixtures/module_cycles and checks
that it fails on every circle, naming exactly the files of the circle and the paths that close
it, and passes on `clean`. Exits 1 if any check fails.
   test_module_cycles.py"""
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
FIXTURES = os.path.join(HERE, 'fixtures', 'module_cycles')

# Fixture crate -> (the cycles it has, each as its files under src/; paths the output names).
EXPECTED = {
    'super_sibling': ([{'shapes/circle.rs', 'shapes/square.rs'}],
                      ['super::square::Square', 'super::circle::Circle']),
    'child_path': ([{'engine/mod.rs', 'engine/parts.rs'}],
                   ['parts::Gear', 'parts::make', 'super::Spec']),
    'crate_path': ([{'map.rs', 'track.rs'}], ['crate::track::Pose', 'crate::map::Map']),
    'use_group': ([{'net/codec.rs', 'net/link.rs'}],
                  ['super::link::send', 'super::codec', 'codec::encode']),
    'three_files': ([{'lib.rs', 'alpha.rs', 'alpha/beta.rs'}],
                    ['alpha::go', 'beta::step', 'crate::Config']),
    'clean': ([], []),
}


def check(name):
    """The failures of fixture crate `name` (none: it passed)."""
    expected_cycles, expected_names = EXPECTED[name]
    crate = os.path.join(FIXTURES, name)
    run = subprocess.run([sys.executable, os.path.join(HERE, 'module_cycles.py'), crate],
                         capture_output=True, text=True)
    src = os.path.join(crate, 'src') + os.sep
    cycles = [{f.strip()[len(src):] for f in line[len(name) + 2:].split(' -> ')}
              for line in run.stdout.splitlines() if line.startswith(name + ': ')]
    failures = []
    if run.returncode != (1 if expected_cycles else 0):
        failures.append(f'exit status {run.returncode}')
    if sorted(map(sorted, cycles)) != sorted(map(sorted, expected_cycles)):
        failures.append(f'cycles {cycles}, expected {expected_cycles}')
    failures += [f'{p} not named' for p in expected_names if f' {p} (line ' not in run.stdout]
    if run.stderr:
        failures.append('stderr: ' + run.stderr)
    return failures, run.stdout


def main():
    fixtures = sorted(d for d in os.listdir(FIXTURES) if os.path.isdir(os.path.join(FIXTURES, d)))
    failed = False
    if fixtures != sorted(EXPECTED):
        print(f'fixtures {fixtures} but expectations for {sorted(EXPECTED)}')
        failed = True
    for name in sorted(EXPECTED):
        failures, output = check(name)
        print(f'{name}: ' + ('ok' if not failures else 'FAILED: ' + '; '.join(failures)))
        if failures:
            print(output)
            failed = True
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
