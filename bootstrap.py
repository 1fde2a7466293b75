#!/usr/bin/env python3
"""Create (or reuse) the local venv in .venv, then run the demo or the test suite.

    python3 bootstrap.py demo   # replay of the bundled demo bag through the monitor
    python3 bootstrap.py test   # the whole test suite

Only python3 is needed: the venv gets the package (editable), ROS 2 Jazzy's Python
client from PyPI and the test tools, then its compiled kernels are cached
(`map-consistency warm-up`). The venv is rebuilt when setup.py or constraints.txt
change. `test` also installs Debian's chromium when it is missing and apt-get can (as root):
the test of batch's HTML page renders it in a headless browser.
"""
import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / '.venv'
PYTHON = VENV / 'bin' / 'python'
STAMP = VENV / '.installed-from'
DEMO_OUTPUT = ROOT / 'out' / 'demo'


def _install_fingerprint() -> str:
    digest = hashlib.sha256()
    for name in ('setup.py', 'constraints.txt'):
        digest.update((ROOT / name).read_bytes())
    return digest.hexdigest()


def _run(command: list[str]) -> int:
    print('+', ' '.join(str(part) for part in command), flush=True)
    return subprocess.call(command, cwd=ROOT)


def ensure_venv() -> None:
    """Create .venv and install the package into it unless it is up to date."""
    fingerprint = _install_fingerprint()
    if STAMP.exists() and STAMP.read_text() == fingerprint:
        return
    if not PYTHON.exists():
        import venv
        try:
            venv.EnvBuilder(with_pip=True).create(VENV)
        except (OSError, subprocess.CalledProcessError) as error:
            sys.exit(f'bootstrap: cannot create {VENV} ({error}); on Debian or Ubuntu the venv '
                     'module is the package python3-venv (apt install python3-venv)')
    install = [str(PYTHON), '-m', 'pip', 'install', '--disable-pip-version-check', '-q',
               '-c', str(ROOT / 'constraints.txt'), '-e', f'{ROOT}[ros,test]']
    if _run(install) != 0:
        sys.exit('bootstrap: installing into .venv failed (see the pip output above)')
    # numba compiles a kernel on its first call: compiled now, into its cache beside the
    # sources, no first command waits for all of them (cli/warm_up.py)
    if _run([str(VENV / 'bin' / 'map-consistency'), 'warm-up']) != 0:
        print('bootstrap: warming the kernels failed; the first command will compile them',
              file=sys.stderr)
    STAMP.write_text(fingerprint)


def ensure_browser() -> None:
    """A headless Chromium for the test of batch's HTML page (test/cli/test_batch.py): on a
    Debian machine where this runs as root, its package is installed once; elsewhere that test
    says what to install."""
    if shutil.which('chromium') or shutil.which('chromium-browser'):
        return
    if os.geteuid() != 0 or not shutil.which('apt-get'):
        return
    install = ['apt-get', 'install', '-y', '-q', 'chromium']
    # a fresh machine may have no package lists yet: fetch them once, then try again
    if _run(install) != 0 and (_run(['apt-get', 'update', '-q']) != 0 or _run(install) != 0):
        print('bootstrap: installing chromium failed; the HTML page test will fail',
              file=sys.stderr)


def main() -> int:
    if len(sys.argv) < 2 or sys.argv[1] not in ('demo', 'test'):
        print(__doc__)
        return 2
    ensure_venv()
    extra = sys.argv[2:]
    if sys.argv[1] == 'demo':
        DEMO_OUTPUT.mkdir(parents=True, exist_ok=True)
        # The demo exits 0 when the corrected map passes and the broken copy fails.
        return _run([str(VENV / 'bin' / 'map-consistency'), 'demo',
                     '--output', str(DEMO_OUTPUT), *extra])
    ensure_browser()
    os.environ.setdefault('PYTHONUNBUFFERED', '1')
    return _run([str(PYTHON), '-m', 'pytest', *extra])


if __name__ == '__main__':
    sys.exit(main())
