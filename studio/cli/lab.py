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
and, unless ``--no-browser``, a browser opens it. The server listens on 127.0.0.1 only, and its token travels in
its environment (``JUPYTER_TOKEN``), never on a command line that any local user can read with ``ps``. Ctrl-C,
SIGTERM and SIGHUP (``studio.cli.signals``; also when ``lab`` runs in the background) stop the server, and then any
kernel it started that is still running (kernels run in sessions of their own): exit code 0. As root (the usual user
in a container) JupyterLab is passed ``--allow-root``, and ``lab`` says so. ``--jupyter-arg=ARG`` passes one more
argument to JupyterLab.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

from studio.cli.flags import ranged
from studio.cli.signals import stop_on_signals
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


def check_port_free(port: int) -> None:
    """A LabError when something on this machine already answers on ``port`` (localhost): JupyterLab could not
    serve there, and the server that answers (a studio started before?) must not be taken for the new one."""
    with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=1.0):
        raise LabError(
            f"port {port} is in use on this machine (a server answers there: a studio or Jupyter started before?): "
            "stop it, pass another --port, or leave it out to take the first free one"
        )


def lab_command(folder: Path, port: int, open_browser: bool, extra: list[str]) -> list[str]:
    """The ``jupyter lab`` command line serving ``folder`` on 127.0.0.1:``port``, opening the studio. No token: it
    goes in the environment (``JUPYTER_TOKEN``), where ``ps`` cannot show it to other users."""
    cmd = [sys.executable, "-m", "jupyterlab", str(folder / NOTEBOOK), f"--ServerApp.root_dir={folder}",
           "--ServerApp.ip=127.0.0.1", f"--port={port}", "--ServerApp.port_retries=0"]  # fmt: skip
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
        except urllib.error.HTTPError as e:
            if e.code == 403:
                raise LabError(
                    "JupyterLab refuses the studio's token: a token set in your Jupyter configuration "
                    "(IdentityProvider.token) overrides it; remove that setting"
                ) from None
            time.sleep(0.3)
        except OSError:
            time.sleep(0.3)
    raise LabError(f"JupyterLab did not answer on port {port} within {timeout_s:.0f} s")


def descendants(pid: int) -> list[tuple[int, str]]:
    """Every process below ``pid``, as ``(pid, start time)`` (the start time tells a process from a later one that
    got its number); empty where there is no ``/proc`` (then the server's own shutdown of its kernels is all)."""
    children: dict[int, list[tuple[int, str]]] = {}
    for entry in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = entry.read_text().rsplit(")", 1)[1].split()  # after "pid (comm)": state, ppid, ...
        except (OSError, IndexError):
            continue  # gone meanwhile, or not ours to read
        children.setdefault(int(fields[1]), []).append((int(entry.parent.name), fields[19]))
    found, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child[0])
    return found


def _alive(pid: int, started: str) -> bool:
    """Whether process ``pid`` still runs (a zombie does not) and is the one that started at ``started`` (not a
    reused number)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return False
    return len(fields) > 19 and fields[19] == started and fields[0] not in ("Z", "X")


def stop(proc: subprocess.Popen, grace_s: float = 15.0) -> None:
    """Stop the server and everything it started: SIGTERM (Jupyter then shuts its kernels down), SIGKILL to its
    process group after ``grace_s``; then any kernel still running (each runs in a session of its own) gets
    SIGTERM, and SIGKILL 3 s later."""
    family = descendants(proc.pid) if proc.poll() is None else []
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(OSError):
                os.killpg(proc.pid, signal.SIGKILL)  # its own session: the group is the server's
            proc.kill()
            proc.wait()
    for sig, wait_s in ((signal.SIGTERM, 3.0), (signal.SIGKILL, 0.0)):
        left = [(pid, t) for pid, t in family if _alive(pid, t)]
        for pid, _ in left:
            with contextlib.suppress(OSError):
                os.kill(pid, sig)
        deadline = time.monotonic() + wait_s
        while left and time.monotonic() < deadline:
            time.sleep(0.1)
            left = [(pid, t) for pid, t in left if _alive(pid, t)]
        if not left:
            return


def _lab(args: argparse.Namespace) -> int:
    from studio.home import studio_home
    from studio.project.demo import demo_project

    if args.port:
        check_port_free(args.port)  # before anything is made or started
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
    env = os.environ | {PROJECT_ENV: str(Path(path).resolve()), "JUPYTER_TOKEN": token}  # not on the command line
    env.pop("JUPYTER_TOKEN_FILE", None)
    if args.clip_weights:
        env[CLIP_ENV] = str(Path(args.clip_weights).expanduser().resolve())
    extra = list(args.jupyter_args)
    if (args.allow_root or _is_root()) and "--allow-root" not in extra:
        extra.append("--allow-root")
        if not args.allow_root:
            print("running as root: JupyterLab is started with --allow-root", file=sys.stderr)
    cmd = lab_command(folder, port, not args.no_browser, extra)
    # Ctrl-C, SIGTERM, SIGHUP raise here (even in the background, where the shell ignores Ctrl-C); the server runs
    # in its own session, so only this process hears them and stops it without Jupyter's y/n prompt
    with stop_on_signals("lab"):
        proc = None
        try:
            proc = subprocess.Popen(cmd, env=env, cwd=folder, stdin=subprocess.DEVNULL, start_new_session=True)
            wait_until_up(proc, port, token)
            print(f"the studio on {path}:\n    http://127.0.0.1:{port}/lab/tree/{NOTEBOOK}?token={token}", flush=True)
            print("Ctrl-C stops JupyterLab", file=sys.stderr, flush=True)
            return proc.wait()
        except KeyboardInterrupt as e:
            print(f"stopping JupyterLab ({e or 'Ctrl-C'})", file=sys.stderr, flush=True)
            return 0
        finally:
            if proc is not None:
                stop(proc)


def _is_root() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("lab", help="the notebook studio in JupyterLab (on PROJECT, or the bundled demo project)")
    p.add_argument("project", nargs="?", help="a project folder NAME.shadow (default: the bundled demo project)")
    p.add_argument("--port", type=ranged(int, "[1024, 65535]"), default=None,
                   help="port to serve on (default: the first free from 8888)")  # fmt: skip
    p.add_argument("--no-browser", action="store_true", help="only print the URL; open no browser")
    p.add_argument("--clip-weights", default=None, help="a local open_clip checkpoint for the CLIP loss terms")
    p.add_argument(
        "--jupyter-arg",
        action="append",
        default=[],
        metavar="ARG",
        dest="jupyter_args",
        help="one more argument for JupyterLab, repeatable (e.g. --jupyter-arg=--notebook-dir=DIR)",
    )
    p.add_argument("--allow-root", action="store_true",
                   help="let JupyterLab run as root (passed by itself when running as root)")  # fmt: skip
    p.set_defaults(func=_lab)
