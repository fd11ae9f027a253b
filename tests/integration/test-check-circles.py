#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""scripts/check-circles on small trees built here with cc: a circle of
two files and one of three are found and named with the symbols that close
them; files that call one way, a module calling another in a circle (not
within one module) and main() in two programs of one folder pass."""
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.realpath(os.path.join(os.path.dirname(__file__), '..', '..'))
SCRIPT = os.path.join(ROOT, 'scripts', 'check-circles')


def build(tree, files):
    """Writes files ({path: text}) under tree/src, compiles each into
    tree/build, and the compile_commands.json that says so."""
    src, out = os.path.join(tree, 'src'), os.path.join(tree, 'build')
    commands = []
    for path, text in files.items():
        os.makedirs(os.path.dirname(os.path.join(src, path)), exist_ok=True)
        with open(os.path.join(src, path), 'w') as f:
            f.write(text)
        obj = path.replace('/', '_') + '.o'
        os.makedirs(out, exist_ok=True)
        subprocess.run(['cc', '-c', '-o', os.path.join(out, obj), os.path.join(src, path)],
                       check=True)
        commands.append({'directory': out, 'file': os.path.join(src, path), 'output': obj})
    with open(os.path.join(out, 'compile_commands.json'), 'w') as f:
        json.dump(commands, f)
    return out, src


def check(files):
    with tempfile.TemporaryDirectory() as tree:
        out, src = build(tree, files)
        r = subprocess.run([sys.executable, SCRIPT, out, src], capture_output=True, text=True)
        return r.returncode, r.stdout


def fn(name, *calls):
    decls = ''.join(f'int {c}(void);\n' for c in calls)
    body = ' + '.join(f'{c}()' for c in calls) or '0'
    return f'{decls}int {name}(void);\nint {name}(void) {{ return {body}; }}\n'


def test_two_files():
    code, out = check({'m/a.c': fn('a_one', 'b_one'), 'm/b.c': fn('b_one', 'a_two') +
                       fn('b_two'), 'm/c.c': fn('c_one', 'b_two'),
                       'm/d.c': fn('a_two')})
    # d.c defines a_two: a -> b -> d, no circle yet
    assert code == 0, out
    code, out = check({'m/a.c': fn('a_one', 'b_one') + fn('a_two'),
                       'm/b.c': fn('b_one', 'a_two'), 'm/c.c': fn('c_one', 'b_one')})
    assert code == 1, out
    assert 'm: a.c, b.c call each other in a circle' in out, out
    assert 'a.c -> b.c: b_one' in out and 'b.c -> a.c: a_two' in out, out
    assert 'c.c' not in out, out


def test_three_files():
    code, out = check({'m/a.c': fn('a_one', 'b_one'), 'm/b.c': fn('b_one', 'c_one'),
                       'm/c.c': fn('c_one', 'a_one'), 'n/x.c': fn('x_one')})
    assert code == 1, out
    assert 'm: a.c, b.c, c.c call each other in a circle' in out, out
    assert out.count('call each other') == 1, out


def test_passes():
    # one way within a module; a circle between two modules is none within one
    code, out = check({'m/a.c': fn('a_one', 'b_one'), 'm/b.c': fn('b_one', 'x_one'),
                       'n/x.c': fn('x_one', 'a_one')})
    assert code == 0, out
    assert 'no circle among the files of any of 2 modules (3 files)' in out, out
    # two programs of one folder each with a main; a helper they share
    code, out = check({'t/one.c': 'int help(void);\nint main(void) { return help(); }\n',
                       't/two.c': 'int help(void);\nint main(void) { return help(); }\n',
                       't/help.c': 'int main(void);\nint help(void);\n'
                                   'int help(void) { return main != help; }\n'})
    assert code == 0, out


def test_no_build():
    with tempfile.TemporaryDirectory() as tree:
        r = subprocess.run([sys.executable, SCRIPT, tree], capture_output=True, text=True)
        assert r.returncode != 0 and 'compile_commands.json' in r.stderr, r.stderr


if __name__ == '__main__':
    for t in (test_two_files, test_three_files, test_passes, test_no_build):
        t()
        print(f'ok - {t.__name__}')
