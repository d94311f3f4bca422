"""A live meshcat viewer whose server process is closed cleanly.

``meshcat.Visualizer()`` starts the meshcat server (``python -m meshcat.servers.zmqserver``)
as a child process in its own session and only kills it at interpreter exit;
``Visualizer.close()`` fails in meshcat 0.3 (``ViewerWindow.close`` does not exist) and
``Visualizer.delete()`` only clears the scene. :class:`LiveViewer` owns the process: it
terminates it, waits for it and closes the pipes and the ZeroMQ socket.
"""

from __future__ import annotations

import contextlib
import io
import subprocess
from types import TracebackType
from typing import Any

import meshcat

from polyhull.errors import PolyhullError

__all__ = ["LiveViewer"]


class LiveViewer:
    """A meshcat server and a visualizer connected to it; a context manager.

    Opening never waits for a browser: the server serves at :attr:`url` until
    :meth:`close` (called on leaving the ``with`` block).

    Example::

        with LiveViewer() as live:
            draw_cell(live.vis, cell)
            print(live.url)
            time.sleep(60)
    """

    def __init__(self) -> None:
        try:
            # meshcat prints the URL itself; the caller decides what to print.
            with contextlib.redirect_stdout(io.StringIO()):
                self._vis: Any = meshcat.Visualizer()
        except (RuntimeError, OSError) as exc:
            raise PolyhullError(f"could not start the meshcat server: {exc}") from exc
        self._closed = False

    @property
    def vis(self) -> Any:
        """The ``meshcat.Visualizer`` to draw into."""
        return self._vis

    @property
    def url(self) -> str:
        """The URL of the viewer page (``http://127.0.0.1:7000/static/``)."""
        return str(self._vis.url())

    @property
    def process(self) -> subprocess.Popen[bytes] | None:
        """The meshcat server process."""
        return self._vis.window.server_proc  # type: ignore[no-any-return]

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` has run."""
        return self._closed

    def close(self, timeout: float = 5.0) -> None:
        """Stop the server: terminate, wait up to ``timeout`` [s], then kill; idempotent."""
        if self._closed:
            return
        self._closed = True
        window = self._vis.window
        with contextlib.suppress(Exception):
            window.zmq_socket.close(linger=0)
        proc = window.server_proc
        if proc is None:
            return
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=timeout)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()

    def __enter__(self) -> LiveViewer:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
