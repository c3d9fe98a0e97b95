"""``shadow-studio lab [PROJECT] [--port N] [--no-browser]``: the notebook studio in JupyterLab.

Starts JupyterLab (the same Python, so the kernel imports this install) on ``studio.ipynb``, which opens the studio
(``widgets.app.open_studio()``) on PROJECT, or on the bundled demo project (made on first use in
``~/.cache/shadow-studio/demo.shadow``; ``$SHADOW_STUDIO_HOME`` moves that folder) when none is given. The project
reaches the notebook through the environment variable ``SHADOW_STUDIO_PROJECT``; ``--clip-weights PATH`` (a local
open_clip checkpoint, never downloaded) through ``SHADOW_STUDIO_CLIP_WEIGHTS``.

The notebook is copied from the checkout's ``notebooks/studio.ipynb`` into ``~/.cache/shadow-studio/lab/`` when it
is not there yet (Lab saves outputs into it; your copy is never overwritten: delete it to get the shipped one
again). That needs a source checkout (``pip install -e .``); a wheel install has no ``notebooks/`` folder.

Once the server answers, its URL with the token is printed (``http://127.0.0.1:PORT/lab/tree/studio.ipynb?token=…``)
and, unless ``--no-browser``, a browser opens it. Ctrl-C stops the server (exit code 0). ``--jupyter-arg=ARG``
passes one more argument to JupyterLab (e.g. ``--jupyter-arg=--allow-root`` as root).
"""

from __future__ import annotations

import argparse
import os
import secrets
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

from studio.errors import StudioError

NOTEBOOK = "studio.ipynb"  # the studio notebook in notebooks/
PROJECT_ENV = "SHADOW_STUDIO_PROJECT"  # read by widgets.app.open_studio (the same name as widgets.app.PROJECT_ENV)
CLIP_ENV = "SHADOW_STUDIO_CLIP_WEIGHTS"  # read by widgets.app.studio_app (widgets.app.CLIP_ENV)
START_TIMEOUT_S = 120.0  # how long JupyterLab may take to answer


class LabError(StudioError):
    """JupyterLab could not be started (the message says why and what to do)."""


def shipped_notebook() -> Path:
    """``notebooks/studio.ipynb`` of the source checkout this package runs from."""
    path = Path(__file__).resolve().parents[2] / "notebooks" / NOTEBOOK
    if not path.is_file():
        raise LabError(f"{NOTEBOOK} is not next to this install ({path} is missing): `shadow-studio lab` runs from a "
                       "source checkout installed with `pip install -e .`")  # fmt: skip
    return path


def lab_folder(home: Path) -> Path:
    """``home/lab`` with the studio notebook in it (copied there when missing) → the folder."""
    folder = home / "lab"
    folder.mkdir(parents=True, exist_ok=True)
    if not (folder / NOTEBOOK).is_file():
        shutil.copyfile(shipped_notebook(), folder / NOTEBOOK)
    return folder


def free_port(start: int = 8888, tries: int = 100) -> int:
    """The first port from ``start`` that nothing listens on (localhost)."""
    for port in range(start, start + tries):
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise LabError(f"no free port in {start}..{start + tries - 1}: pass --port N")


def lab_command(folder: Path, port: int, token: str, open_browser: bool, extra: list[str]) -> list[str]:
    """The ``jupyter lab`` command line serving ``folder`` on ``port`` with ``token``, opening the studio."""
    cmd = [sys.executable, "-m", "jupyterlab", str(folder / NOTEBOOK), f"--ServerApp.root_dir={folder}",
           f"--port={port}", "--ServerApp.port_retries=0", f"--IdentityProvider.token={token}"]  # fmt: skip
    if not open_browser:
        cmd.append("--no-browser")
    return cmd + extra


def wait_until_up(proc: subprocess.Popen, port: int, token: str, timeout_s: float = START_TIMEOUT_S) -> None:
    """Return once the server answers ``/api/status``; a LabError if it exits or stays silent."""
    deadline = time.monotonic() + timeout_s
    url = f"http://127.0.0.1:{port}/api/status?token={token}"
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise LabError(f"JupyterLab exited with code {proc.returncode} (its messages are above)")
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                if r.status == 200:
                    return
        except OSError:
            time.sleep(0.3)
    raise LabError(f"JupyterLab did not answer on port {port} within {timeout_s:.0f} s")


def stop(proc: subprocess.Popen) -> None:
    """Stop the server (SIGTERM: it shuts its kernels down), killing it after 15 s."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _lab(args: argparse.Namespace) -> int:
    from studio.home import studio_home
    from studio.project.demo import demo_project

    home = studio_home()
    if args.project is None:
        project, fresh = demo_project(home)
        print(f"{'made' if fresh else 'opening'} the demo project {project.path}", file=sys.stderr)
        path = project.path
    else:
        from studio.project.project import Project

        path = Project.open(args.project).path  # a typed error now rather than in the notebook
    folder = lab_folder(home)
    port = args.port or free_port()
    token = secrets.token_hex(24)
    env = os.environ | {PROJECT_ENV: str(Path(path).resolve())}
    if args.clip_weights:
        env[CLIP_ENV] = str(Path(args.clip_weights).expanduser().resolve())
    cmd = lab_command(folder, port, token, not args.no_browser, args.jupyter_args)
    # its own session: Ctrl-C reaches only this process, which then stops the server without Jupyter's y/n prompt
    proc = subprocess.Popen(cmd, env=env, cwd=folder, stdin=subprocess.DEVNULL, start_new_session=True)
    try:
        wait_until_up(proc, port, token)
        print(f"the studio on {path}:\n    http://127.0.0.1:{port}/lab/tree/{NOTEBOOK}?token={token}", flush=True)
        print("Ctrl-C stops JupyterLab", file=sys.stderr, flush=True)
        return proc.wait()
    except KeyboardInterrupt:
        print("stopping JupyterLab", file=sys.stderr)
        return 0
    finally:
        stop(proc)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("lab", help="the notebook studio in JupyterLab (on PROJECT, or the bundled demo project)")
    p.add_argument("project", nargs="?", help="a project folder NAME.shadow (default: the bundled demo project)")
    p.add_argument("--port", type=int, default=None, help="port to serve on (default: the first free from 8888)")
    p.add_argument("--no-browser", action="store_true", help="only print the URL; open no browser")
    p.add_argument("--clip-weights", default=None, help="a local open_clip checkpoint for the CLIP loss terms")
    p.add_argument(
        "--jupyter-arg",
        action="append",
        default=[],
        metavar="ARG",
        dest="jupyter_args",
        help="one more argument for JupyterLab, repeatable (e.g. --jupyter-arg=--allow-root)",
    )
    p.set_defaults(func=_lab)
