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
import urllib.error
import urllib.request

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
    assert done.returncode == 2 and "not a project" in done.stderr
    assert not (tmp_path / "home" / "lab").exists()  # nothing started, nothing copied
