"""``shadow-studio lab``: JupyterLab serving the studio notebook (copied into the user folder) on the given project,
its URL printed with the token once it answers, the project passed to the kernel's environment, Ctrl-C stopping
it; a folder that is not a project refused before anything starts."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request

import psutil
import pytest
from studio.assets import asset

from studio.cli.lab import free_port
from studio.project.project import Project


def get(url: str) -> int:
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            return r.status
    except urllib.error.HTTPError as e:
        return e.code


@pytest.mark.slow
def test_lab_serves_the_studio_notebook_and_ctrl_c_stops_it(tmp_path):
    project = Project.create(tmp_path / "mine.shadow", sources=[asset("targets/asl_o.jpeg")])
    home, port = tmp_path / "home", free_port(19888)
    env = os.environ | {"SHADOW_STUDIO_HOME": str(home), "JUPYTER_CONFIG_DIR": str(tmp_path / "config"),
                        "JUPYTER_RUNTIME_DIR": str(tmp_path / "runtime")}  # fmt: skip
    cmd = [sys.executable, "-m", "studio.cli.main", "lab", str(project.path), "--port", str(port), "--no-browser",
           "--jupyter-arg=--allow-root"]  # fmt: skip
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        url = None
        for line in proc.stdout:
            if m := re.search(rf"http://127\.0\.0\.1:{port}/lab/tree/studio\.ipynb\?token=(\w+)", line):
                url, token = m.group(0), m.group(1)
                break
        assert url, f"no URL printed (exit code {proc.poll()})"
        base = f"http://127.0.0.1:{port}"
        assert get(f"{base}/api/status?token={token}") == 200
        assert get(f"{base}/api/status") == 403  # the token is needed
        with urllib.request.urlopen(f"{base}/api/contents/studio.ipynb?token={token}", timeout=5) as r:
            model = json.load(r)
        assert "open_studio()" in json.dumps(model["content"])  # the notebook served from the user folder
        assert (home / "lab" / "studio.ipynb").is_file()
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        assert proc.wait(30) == 0
        with pytest.raises(OSError):
            urllib.request.urlopen(f"{base}/api/status?token={token}", timeout=2)
    finally:
        if proc.poll() is None:
            proc.kill()


def test_lab_refuses_a_folder_that_is_not_a_project(tmp_path):
    env = os.environ | {"SHADOW_STUDIO_HOME": str(tmp_path / "home")}
    cmd = [sys.executable, "-m", "studio.cli.main", "lab", str(tmp_path / "nothing.shadow"), "--no-browser"]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "project not found" in done.stderr, done.stderr
    assert not (tmp_path / "home" / "lab").exists()  # nothing started, nothing copied
    image = tmp_path / "horse.gif"  # a source given where its project goes: how to make the project of it
    image.write_bytes(b"GIF89a")
    done = subprocess.run([*cmd[:-2], str(image), "--no-browser"], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "horse.gif is a file" in done.stderr, done.stderr
    assert f"project new horse.shadow --source {image}" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "home" / "lab").exists()


def test_lab_refuses_a_port_another_server_answers_on(tmp_path, monkeypatch, capsys):
    """`--port N` where a server already listens (a studio started before): one line saying so, before anything is
    made or started (it was taken for JupyterLab refusing the studio's token: the old server answered 403)."""
    import socket

    from studio.cli.main import main

    monkeypatch.setenv("SHADOW_STUDIO_HOME", str(tmp_path / "home"))
    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen()
        port = other.getsockname()[1]
        assert main(["lab", "--port", str(port), "--no-browser"]) == 2
    err = capsys.readouterr().err
    assert f"port {port} is in use on this machine" in err and "pass another --port" in err and "token" not in err, err
    assert "Traceback" not in err and not (tmp_path / "home").exists()  # no demo project made, no notebook copied


def family(pid: int) -> list[psutil.Process]:
    """The processes below ``pid`` that still run."""
    try:
        return running(psutil.Process(pid).children(recursive=True))
    except psutil.NoSuchProcess:
        return []


def running(procs: list[psutil.Process]) -> list[psutil.Process]:
    """Those of ``procs`` that still run (a zombie does not)."""
    out = []
    for p in procs:
        try:
            if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except psutil.NoSuchProcess:
            pass
    return out


def cmdline(p: psutil.Process) -> list[str]:
    """``p``'s command line; empty once it has exited (the server starts short-lived helpers)."""
    try:
        return p.cmdline()
    except (psutil.NoSuchProcess, psutil.ZombieProcess):
        return []


@pytest.mark.slow
@pytest.mark.parametrize("how", ["SIGTERM", "Ctrl-C in the background"])
def test_a_stop_signal_ends_lab_its_server_and_its_kernels_and_the_token_is_on_no_command_line(tmp_path, how):
    """`lab` with a kernel running: nothing it started listens beyond 127.0.0.1, no command line carries the token,
    and SIGTERM (or Ctrl-C's SIGINT to a `lab &` whose shell ignores SIGINT) stops lab, the server and the kernel."""
    project = Project.create(tmp_path / "mine.shadow", sources=[asset("targets/asl_o.jpeg")])
    port = free_port(19988)
    env = os.environ | {"SHADOW_STUDIO_HOME": str(tmp_path / "home"), "JUPYTER_CONFIG_DIR": str(tmp_path / "config"),
                        "JUPYTER_RUNTIME_DIR": str(tmp_path / "runtime")}  # fmt: skip
    cmd = [sys.executable, "-m", "studio.cli.main", "lab", str(project.path), "--port", str(port), "--no-browser"]
    background = how != "SIGTERM"
    ignore_sigint = (lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if background else None
    with open(tmp_path / "stderr.txt", "w") as err:  # a file: Jupyter's log would fill a pipe nobody reads
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=err, text=True, preexec_fn=ignore_sigint)
    started = []
    try:
        token = None
        for line in proc.stdout:
            if m := re.search(rf"http://127\.0\.0\.1:{port}/lab/tree/studio\.ipynb\?token=(\w+)", line):
                token = m.group(1)
                break
        assert token, f"no URL printed (exit code {proc.poll()}): {(tmp_path / 'stderr.txt').read_text()[-2000:]}"
        request = urllib.request.Request(
            f"http://127.0.0.1:{port}/api/kernels?token={token}",
            data=b'{"name": "python3"}',
            headers={"Content-Type": "application/json"},
            method="POST",
        )
        with urllib.request.urlopen(request, timeout=30) as r:
            assert r.status == 201
        deadline = time.monotonic() + 60
        while not any("ipykernel" in " ".join(cmdline(p)) for p in family(proc.pid)):
            assert time.monotonic() < deadline, "the kernel did not start"
            time.sleep(0.2)
        started = [psutil.Process(proc.pid), *family(proc.pid)]
        for p in started:
            assert token not in "\0".join(cmdline(p)), cmdline(p)  # what `ps` shows any local user
            try:
                socks = {c.laddr.ip for c in p.net_connections("tcp") if c.status == "LISTEN"}
            except psutil.NoSuchProcess:  # a helper that has exited listens nowhere
                socks = set()
            assert socks <= {"127.0.0.1"}, (cmdline(p), socks)
        if os.geteuid() == 0:  # as root, lab passes --allow-root itself and says so
            assert "--allow-root" in started[1].cmdline()
            assert "running as root: JupyterLab is started with --allow-root" in (tmp_path / "stderr.txt").read_text()
        proc.send_signal(signal.SIGTERM if how == "SIGTERM" else signal.SIGINT)
        assert proc.wait(60) == 0
        deadline = time.monotonic() + 10
        while running(started) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not running(started), [cmdline(p) for p in running(started)]
        assert "stopping JupyterLab" in (tmp_path / "stderr.txt").read_text()
    finally:
        for p in running(started):
            p.kill()
        if proc.poll() is None:
            proc.kill()
