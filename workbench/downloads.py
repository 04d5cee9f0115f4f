"""Files the browser saves: exports streamed by a small HTTP server in the kernel, from a temp dir.

Why not a ``data:`` link: the whole file then travels inside the page's HTML (a 59 MB STL of
the microstructure became an 80 MB widget value).  Why not the Jupyter server's files handler:
it serves only files under its root, the repository, where exports would show up in git.
So the kernel, which already serves the trame 3-D view the same way, serves each export from
its own temporary directory (outside the repository, removed when the kernel exits) at an
unguessable address, streamed in chunks with ``Content-Disposition: attachment``: a click
saves the file and the page stays.  The address is built like pyvista's trame viewer's
(``http://localhost:<port>/`` or, behind jupyter-server-proxy, pyvista's proxy prefix), so the
link works wherever the 3-D view does.
"""

from __future__ import annotations

import atexit
import html
import http.server
import os
import secrets
import shutil
import tempfile
import threading
import urllib.parse

__all__ = ["Downloads", "downloads"]

CHUNK = 1 << 20  # bytes per write: memory stays bounded whatever the file's size
KEEP = 16  # exports kept per kernel; older ones are deleted


class Downloads:
    """A temporary directory of exports and the HTTP server that streams them.

    Examples
    --------
    >>> import urllib.request
    >>> d = Downloads()
    >>> path = d.new_path("cube.stl")
    >>> _ = open(path, "wb").write(b"solid cube")
    >>> url = d.url(path, host="127.0.0.1")
    >>> with urllib.request.urlopen(url) as r:
    ...     r.read(), r.headers["Content-Disposition"]
    (b'solid cube', 'attachment; filename="cube.stl"')
    >>> os.path.commonpath([path, os.getcwd()]) == os.getcwd()  # never in the working tree
    False
    >>> d.close()
    """

    def __init__(self) -> None:
        self.directory = tempfile.mkdtemp(prefix="pyfrep-exports-")
        self.token = secrets.token_urlsafe(16)
        self._files: dict[str, str] = {}  # url path -> file path
        self._order: list[str] = []
        self._lock = threading.Lock()
        self._server: http.server.ThreadingHTTPServer | None = None
        atexit.register(self.close)

    # -- files ------------------------------------------------------------------------------------
    def new_path(self, name: str) -> str:
        """A fresh file path for an export called ``name`` (its own subdirectory: names may repeat)."""
        base = os.path.basename(name)
        if not base or base in (".", ".."):
            raise ValueError(f"Downloads.new_path: name must be a file name, got {name!r}")
        folder = tempfile.mkdtemp(dir=self.directory)
        return os.path.join(folder, base)

    def url(self, path: str, host: str = "localhost") -> str:
        """The address that streams ``path`` (a file from :meth:`new_path`) as an attachment."""
        path = os.path.abspath(path)
        if os.path.dirname(os.path.dirname(path)) != self.directory or not os.path.isfile(path):
            raise ValueError(f"Downloads.url: {path!r} is not an export written to {self.directory}")
        port = self._start()
        key = f"/{self.token}/{os.path.basename(os.path.dirname(path))}/{urllib.parse.quote(os.path.basename(path))}"
        with self._lock:
            self._files[key] = path
            self._order.append(key)
            while len(self._order) > KEEP:  # bounded disk use: the oldest export goes
                old = self._files.pop(self._order.pop(0), None)
                if old is not None:
                    shutil.rmtree(os.path.dirname(old), ignore_errors=True)
        try:
            import pyvista as pv

            trame = pv.global_theme.trame
            if trame.server_proxy_enabled:
                return f"{trame.server_proxy_prefix or ''}{port}{key}"
        except (ImportError, AttributeError):
            pass
        return f"http://{host}:{port}{key}"

    def link(self, path: str, text: str | None = None) -> str:
        """HTML: a link that saves ``path``, with its name and size."""
        name = os.path.basename(path)
        size = os.path.getsize(path)
        label = text or f"download {name}"
        url = self.url(path)
        # opened in a hidden frame of its own: navigating the page itself (even to a file it then
        # saves) fires its beforeunload, where Voila shuts the kernel down and the views disconnect
        frame = "pyfrep-download-" + url.rsplit("/", 2)[-2]
        return (
            f"<a class='pyfrep-download' href='{html.escape(url)}' target='{frame}' "
            f"download='{html.escape(name)}' style='color:#0645ad;text-decoration:underline'>"
            f"{html.escape(label)}</a> ({_size(size)})"
            f"<iframe name='{frame}' title='download' style='display:none'></iframe>"
        )

    # -- server -----------------------------------------------------------------------------------
    def _start(self) -> int:
        with self._lock:
            if self._server is None:
                files, lock = self._files, self._lock

                class Handler(http.server.BaseHTTPRequestHandler):
                    def do_GET(self) -> None:  # noqa: N802  (http.server's name)
                        with lock:
                            path = files.get(urllib.parse.urlsplit(self.path).path)
                        if path is None or not os.path.isfile(path):
                            self.send_error(404, "no such export")
                            return
                        name = os.path.basename(path)
                        self.send_response(200)
                        self.send_header("Content-Type", "application/octet-stream")
                        self.send_header("Content-Length", str(os.path.getsize(path)))
                        self.send_header("Content-Disposition", f'attachment; filename="{name}"')
                        self.send_header("Cache-Control", "no-store")
                        self.end_headers()
                        with open(path, "rb") as fh:
                            shutil.copyfileobj(fh, self.wfile, CHUNK)

                    def log_message(self, *args: object) -> None:  # quiet: a kernel's stderr is the page
                        pass

                host = os.environ.get("TRAME_DEFAULT_HOST", "127.0.0.1")  # where trame's view listens too
                self._server = http.server.ThreadingHTTPServer((host, 0), Handler)
                self._server.daemon_threads = True
                threading.Thread(target=self._server.serve_forever, name="pyfrep-downloads", daemon=True).start()
            return self._server.server_address[1]

    def close(self) -> None:
        """Stop the server and delete every export."""
        with self._lock:
            server, self._server = self._server, None
            self._files.clear()
            self._order.clear()
        if server is not None:
            server.shutdown()
            server.server_close()
        shutil.rmtree(self.directory, ignore_errors=True)


def _size(n: int) -> str:
    return f"{n} bytes" if n < 1000 else f"{n / 1000:.1f} kB" if n < 1_000_000 else f"{n / 1e6:.1f} MB"


_shared: Downloads | None = None
_shared_lock = threading.Lock()


def downloads() -> Downloads:
    """The kernel's one :class:`Downloads` (created on first use)."""
    global _shared
    with _shared_lock:
        if _shared is None:
            _shared = Downloads()
        return _shared
