"""Check that every surviving mutant of a filter mutation run has a disposition in
bench/results/mutation.md, and that the results list no mutant the run killed.

    bash bench/mutation.sh filter > /tmp/filter.txt; python3 bench/mutation_check.py /tmp/filter.txt

The results name survivors either one by one (`` `module.fn #k` ``) or grouped by function
(`` `module.fn` #a, #b ``), in the section that starts with SECTION, up to "Noticed, left
alone:". Exit status 1 if the two disagree.
"""
import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent / 'results' / 'mutation.md'
SECTION = '**Run of the split filter**'


def survivors(run_output: str) -> set:
    """Short names (``inputs.RobotFilter.step #3``, ``law.govern #31``) of the survived / not
    covered mutants."""
    names = set()
    for line in run_output.splitlines():
        if not line.startswith('--- supersafe_ros.filter.'):
            continue
        module, mangled = line.split('supersafe_ros.filter.', 1)[1].strip().split('.', 1)
        m = re.match(r'xǁ(\w+)ǁ(\w+?)__mutmut_(\d+)$', mangled) or re.match(r'x_(\w+?)__mutmut_(\d+)$', mangled)
        if m is None:
            raise SystemExit(f'cannot read mutant name {mangled!r}')
        *fn, k = m.groups()
        names.add(f'{module}.{".".join(fn)} #{k}')
    return names


def documented(docs: str) -> set:
    if SECTION not in docs:
        raise SystemExit(f'{DOCS} has no section {SECTION!r} yet: record a run of the split filter there')
    text = docs[docs.index(SECTION):]
    text = text[:text.index('Noticed, left alone:')]
    names = set(re.findall(r'`([\w.]+ #\d+)`', text))
    for fn, numbers in re.findall(r'`([\w.]+)` ((?:#\d+(?:, )?)+)', text):
        names.update(f'{fn} {k}' for k in re.findall(r'#\d+', numbers))
    return names


def main(argv):
    run = survivors(Path(argv[1]).read_text())
    docs = documented(DOCS.read_text())
    missing, extra = sorted(run - docs), sorted(docs - run)
    print(f'{len(run)} survivors in the run, {len(docs)} named in the docs')
    for label, names in (('not in the docs', missing), ('in the docs but not surviving', extra)):
        if names:
            print(f'{label} ({len(names)}): ' + ', '.join(names))
    return 1 if missing or extra else 0


if __name__ == '__main__':
    raise SystemExit(main(sys.argv))
