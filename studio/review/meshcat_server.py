"""A meshcat server that listens on 127.0.0.1 only, for :class:`studio.review.scene.ShadowScene`.

meshcat 0.3.2's own server (``meshcat.servers.zmqserver``, which ``meshcat.Visualizer()`` starts) binds its zmq socket
to 127.0.0.1 but its web server (the viewer page and its websocket, no authentication) to every interface, 0.0.0.0
and [::], and has no option to change that. This module runs the same bridge with the web server bound to
``HOST`` too, as ``python -m studio.review.meshcat_server``; :func:`start_local_server` starts it the way meshcat
starts its own (its own session, so a notebook's interrupt does not stop it) and reads the two URLs it prints. It is
killed when the studio's interpreter exits, and stops by itself within a second or two when the process that started
it is gone without that (a kernel killed, an abort), so no server is left holding its ports.
"""

from __future__ import annotations

import atexit
import os
import subprocess
import sys
import tempfile

import tornado.ioloop
from meshcat.servers import zmqserver

from studio.errors import StudioError

HOST = "127.0.0.1"  # the only address either listener binds
PARENT_CHECK_MS = 1000  # ms between two looks at whether the process that started the server is still there


class LocalBridge(zmqserver.ZMQWebSocketBridge):
    """meshcat's zmq ↔ websocket bridge with its web server bound to :data:`HOST` (its zmq socket already is)."""

    def __init__(self) -> None:
        super().__init__(host=HOST)

    def make_app(self):
        app = super().make_app()
        listen = app.listen
        app.listen = lambda port, **kwargs: listen(port, address=HOST, **kwargs)  # meshcat passes no address
        return app


def start_local_server(timeout_lines: int = 2000) -> tuple[subprocess.Popen, str, str]:
    """Start the server; returns ``(process, zmq_url, web_url)``. The process is killed at interpreter exit if it
    still runs (as meshcat does for its own). Raises ``StudioError`` with the server's messages if it exits first."""
    errors = tempfile.TemporaryFile()  # not a pipe: the server logs every websocket, and a full pipe would stall it
    proc = subprocess.Popen([sys.executable, "-u", "-m", __name__], stdout=subprocess.PIPE, stderr=errors,
                            stdin=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
    with errors:  # the child keeps its own copy
        urls: dict[str, str] = {}
        for _ in range(timeout_lines):
            line = proc.stdout.readline().decode("utf-8", "replace").strip()
            key, _, value = line.partition("=")
            if key in ("zmq_url", "web_url"):
                urls[key] = value
            if len(urls) == 2:
                atexit.register(_kill, proc)
                return proc, urls["zmq_url"], urls["web_url"]
            if not line and proc.poll() is not None:
                break
        _kill(proc)
        errors.seek(0)
        said = errors.read().decode("utf-8", "replace").strip().splitlines()[-1:] or ["no message"]
    raise StudioError(f"the meshcat server did not start (exit code {proc.returncode}: {said[0]})")


def _kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait()


def main() -> None:
    bridge = LocalBridge()
    parent = os.getppid()

    def orphaned() -> None:  # the studio that started it is gone without stopping it (killed, or aborted)
        if os.getppid() != parent:
            bridge.ioloop.stop()

    tornado.ioloop.PeriodicCallback(orphaned, PARENT_CHECK_MS).start()
    print(f"zmq_url={bridge.zmq_url}", flush=True)
    print(f"web_url={bridge.web_url}", flush=True)
    try:
        bridge.run()
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
