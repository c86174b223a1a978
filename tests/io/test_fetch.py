"""``less fetch`` against a real HTTP server on 127.0.0.1 serving a fixture record (a zip of two scans)."""

import hashlib
import http.server
import json
import threading
import typing

import pytest
from published_fixture import write_archive

from lesscli.data.archive import record_files
from lesscli.errors import DataError

GOOD, CORRUPT, DEAD = "101", "102", "103"


class Archive(http.server.BaseHTTPRequestHandler):
    """Serves /api/records/<id> as JSON and /files/<name> with range requests.

    ``cut`` names files whose first transfer stops half-way (the connection closes); ``served``
    overrides the bytes sent for a file (a corrupt copy); ``log`` records (path, Range header).
    """

    records: typing.ClassVar[dict] = {}
    files: typing.ClassVar[dict] = {}
    served: typing.ClassVar[dict] = {}
    cut: typing.ClassVar[set] = set()
    whole: typing.ClassVar[set] = set()     # files whose range requests get the whole file (200) anyway
    log: typing.ClassVar[list] = []

    def log_message(self, *args):          # keep the test output clean
        pass

    def do_GET(self):
        self.log.append((self.path, self.headers.get("Range")))
        if self.path.startswith("/api/records/") and self.path.rsplit("/", 1)[1] in self.records:
            return self._send(200, json.dumps(self.records[self.path.rsplit("/", 1)[1]]).encode(),
                              "application/json")
        name = self.path.removeprefix("/files/")
        if name not in self.files:
            return self._send(404, b"not found", "text/plain")
        data = self.served.get(name, self.files[name])
        start = (int(self.headers["Range"].removeprefix("bytes=").rstrip("-")) if self.headers.get("Range")
                 else 0)
        start = 0 if name in self.whole else start
        if start:
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
        else:
            self.send_response(200)
        self.send_header("Content-Length", str(len(data) - start))
        self.end_headers()
        if name in self.cut:
            self.cut.discard(name)
            self.wfile.write(data[: len(data) // 2])   # then the connection closes mid-file
            return
        self.wfile.write(data[start:])

    def _send(self, code, body, kind):
        self.send_response(code)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)


def _entry(base, name, data):
    return {"key": name, "size": len(data), "checksum": f"md5:{hashlib.md5(data).hexdigest()}",
            "links": {"self": f"{base}/files/{name}"}}


@pytest.fixture
def archive(tmp_path):
    """A running server and its base URL; record 101 holds dataset_poke.zip (first transfer cut)."""
    with open(write_archive(str(tmp_path / "src" / "dataset_poke.zip")), "rb") as fh:
        zipped = fh.read()
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Archive)
    base = f"http://127.0.0.1:{server.server_address[1]}"
    corrupt = bytearray(zipped)
    corrupt[len(corrupt) // 3] ^= 0xFF
    Archive.files = {"dataset_poke.zip": zipped, "bad.zip": zipped}
    Archive.served = {"bad.zip": bytes(corrupt)}
    Archive.records = {GOOD: {"id": int(GOOD), "files": [_entry(base, "dataset_poke.zip", zipped)]},
                       CORRUPT: {"id": int(CORRUPT), "files": [_entry(base, "bad.zip", zipped)]},
                       DEAD: {"id": int(DEAD), "files": [_entry(base, "gone.zip", b"x")]}}
    Archive.cut, Archive.whole, Archive.log = {"dataset_poke.zip"}, set(), []
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield base, zipped
    server.shutdown()
    server.server_close()


def test_fetch_resumes_a_broken_transfer_and_the_archive_imports(archive, run_less, tmp_path):
    base, zipped = archive
    proc = run_less("-v", "fetch", GOOD, "-o", tmp_path / "data", "--base-url", base, check=True)
    out = tmp_path / "data" / "dataset_poke.zip"
    assert out.read_bytes() == zipped and not (tmp_path / "data" / "dataset_poke.zip.part").exists()
    row = json.loads(proc.stdout)
    assert row["status"] == "resumed" and row["bytes"] == len(zipped) and row["record"] == GOOD
    gets = [rng for path, rng in Archive.log if path == "/files/dataset_poke.zip"]
    assert gets == [None, f"bytes={len(zipped) // 2}-"]            # whole file, then the rest only
    err = proc.stderr.decode()                                       # the byte progress in a log (a pipe):
    assert "dataset_poke.zip: 523.6 KiB/523.6 KiB (100 %)" in err      # plain lines, no cursor codes
    assert "\r" not in err and "\x1b" not in err
    again = run_less("fetch", GOOD, "-o", tmp_path / "data", "--base-url", base, check=True)
    assert json.loads(again.stdout)["status"] == "present" and len(gets) == 2 == len(
        [p for p, _ in Archive.log if p == "/files/dataset_poke.zip"])
    imported = run_less("import", out, "-o", tmp_path / "poke.npz", check=True)
    assert [json.loads(line)["status"] for line in imported.stdout.decode().splitlines()] == ["ok", "ok"]


def test_fetch_continues_a_part_left_by_an_earlier_run(archive, run_less, tmp_path):
    base, zipped = archive
    Archive.cut = set()
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "dataset_poke.zip.part").write_bytes(zipped[:1000])
    proc = run_less("fetch", GOOD, "-o", tmp_path / "data", "--base-url", base, check=True)
    assert json.loads(proc.stdout)["status"] == "resumed"
    assert (tmp_path / "data" / "dataset_poke.zip").read_bytes() == zipped
    assert [r for p, r in Archive.log if p.startswith("/files/")] == ["bytes=1000-"]


def test_corrupt_file_is_refused_with_one_line_and_nothing_left(archive, run_less, tmp_path):
    base, _ = archive
    proc = run_less("-q", "fetch", CORRUPT, "-o", tmp_path / "data", "--base-url", base)
    err = proc.stderr.decode().strip().splitlines()
    assert proc.returncode == 1 and len(err) == 1 and "bad.zip: checksum mismatch" in err[0]
    # sent whole in one transfer: fetching again would give the same bytes, and the line says so
    assert "one whole transfer" in err[0] and "run again" not in err[0]
    assert list((tmp_path / "data").iterdir()) == []


def test_a_mismatch_of_a_joined_download_says_a_fresh_fetch_may_help(archive, run_less, tmp_path):
    base, _ = archive
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "bad.zip.part").write_bytes(b"stale bytes of another version")
    proc = run_less("fetch", CORRUPT, "-o", tmp_path / "data", "--base-url", base)
    err = [line for line in proc.stderr.decode().strip().splitlines() if "%)" not in line]   # not progress
    assert (proc.returncode == 1 and len(err) == 1 and "joined from 2 transfers" in err[0]
            and "fresh" in err[0])
    assert list((tmp_path / "data").iterdir()) == []


def test_a_server_that_resends_the_whole_file_is_downloaded_not_resumed(archive, run_less, tmp_path):
    base, zipped = archive
    Archive.whole = {"dataset_poke.zip"}              # the first transfer breaks off; the retry gets 200
    proc = run_less("fetch", GOOD, "-o", tmp_path / "data", "--base-url", base, check=True)
    assert json.loads(proc.stdout)["status"] == "downloaded"
    assert (tmp_path / "data" / "dataset_poke.zip").read_bytes() == zipped
    assert [r for p, r in Archive.log if p.startswith("/files/")] == [None, f"bytes={len(zipped) // 2}-"]


def test_dead_link_and_unknown_record_are_one_line_errors(archive, run_less, tmp_path):
    base, _ = archive
    proc = run_less("fetch", DEAD, "-o", tmp_path / "data", "--base-url", base)
    err = proc.stderr.decode().strip().splitlines()
    assert proc.returncode == 1 and len(err) == 1 and "/files/gone.zip: HTTP 404" in err[0]
    proc = run_less("fetch", "999", "-o", tmp_path / "data", "--base-url", base)
    assert proc.returncode == 1 and "/api/records/999: HTTP 404" in proc.stderr.decode()
    proc = run_less("fetch", "pokes", "-o", tmp_path / "data", "--base-url", base)
    assert proc.returncode == 1 and "record 'pokes'" in proc.stderr.decode()
    proc = run_less("fetch", GOOD, "--file", "other.zip", "-o", tmp_path / "data", "--base-url", base)
    assert proc.returncode == 1 and "other.zip: not a file of record(s) 101" in proc.stderr.decode()
    assert not list((tmp_path / "data").glob("*"))


def test_record_files_reads_both_shapes_of_the_description():
    new = {"files": [{"key": "a.zip", "size": 3, "checksum": "md5:" + "A" * 32,
                      "links": {"self": "/api/records/7/files/a.zip",
                                "content": "/api/records/7/files/a.zip/content"}}]}
    old = {"files": [{"filename": "a.zip", "filesize": 3, "checksum": "a" * 32}]}
    entries = {"files": {"entries": {"a.zip": {"key": "a.zip", "size": 3, "checksum": "md5:" + "a" * 32}}}}
    got = [record_files(d, "http://h/", "7")[0] for d in (new, old, entries)]
    assert {f.url for f in got} == {"http://h/api/records/7/files/a.zip/content"}
    assert {(f.name, f.size, f.md5) for f in got} == {("a.zip", 3, "a" * 32)}
    with pytest.raises(DataError, match="unusable name '../x'"):
        record_files({"files": [{"key": "../x"}]}, "http://h", "7")
    with pytest.raises(DataError, match="not md5"):
        record_files({"files": [{"key": "x", "checksum": "sha256:00"}]}, "http://h", "7")
