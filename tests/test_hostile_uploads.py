"""Hostile and accidental uploads (issue 41): every file of the corpus (tests/hostile_corpus.py,
built small here) is a 4xx naming its problem, answered at once and briefly; the file is read
in a process of its own under time and memory limits, in a heavy-request slot (503 when none
is free), stopped when its client leaves, while /v1/health keeps answering; long names keep
their suffix; valid compressed files read as the plain ones."""

from __future__ import annotations

import bz2
import gzip
import io
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import numpy as np
import psutil
import pytest
from astropy.table import Table
from fastapi.testclient import TestClient
from hostile_corpus import Attack, build

from service.app import create_app
from service.settings import Settings
from service.tables import read_targets

SIZE_BYTES = 2_000_000  # the big files of the corpus
DECOMPRESSED_BYTES = 1_000_000  # the server's MXS_MAX_UPLOAD_DECOMPRESSED_BYTES here
BOMB_BYTES = 3_000_000
MAX_ANSWER_S = 10.0
MAX_ANSWER_BYTES = 1000


def _settings(tmp: Path, **kw: object) -> Settings:
    base: dict[str, object] = {"job_db": tmp / "jobs.sqlite3", "workers": 1,
                               "max_upload_decompressed_bytes": DECOMPRESSED_BYTES,
                               "max_target_list_targets": 10_000}
    return Settings(**{**base, **kw})


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Attack]:
    return {a.name: a for a in build(tmp_path_factory.mktemp("corpus"), SIZE_BYTES, BOMB_BYTES)}


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    with TestClient(create_app(_settings(tmp_path_factory.mktemp("db")))) as c:
        yield c


def _post(c: TestClient | httpx.Client, name: str, data: bytes) -> httpx.Response:
    return c.post("/v1/target-lists", params={"include_targets": "false"},
                  files={"file": (name, data)})


ATTACKS = [
    "duplicate_columns_40kb", "duplicate_columns_to_limit", "repeated_name", "empty_name",
    "long_ra_cell_30kb", "long_cell_to_limit", "many_rows", "many_columns", "ecsv_huge_header",
    "votable_many_rows", "fits_many_rows", "fits_truncated", "gzip_declared_rows", "gzip_bomb",
    "bzip2_bomb", "xz_bomb_named_csv", "gzip_twice", "zip", "many_hdus"]


@pytest.mark.parametrize("name", ATTACKS)
def test_each_hostile_file_is_a_4xx_naming_its_problem(client: TestClient,
                                                        corpus: dict[str, Attack],
                                                        name: str) -> None:
    att = corpus[name]
    t0 = time.monotonic()
    r = _post(client, att.filename, att.path.read_bytes())
    took_s = time.monotonic() - t0
    assert r.status_code in att.statuses, (r.status_code, r.text[:300])
    assert att.says in r.text, r.text[:300]
    assert took_s < MAX_ANSWER_S
    assert len(r.content) < MAX_ANSWER_BYTES, r.text[:300]  # at most ~100 characters echoed


def test_the_corpus_is_the_whole_list(corpus: dict[str, Attack]) -> None:
    assert sorted(corpus) == sorted(ATTACKS)


def test_a_refused_table_names_the_file_row_line_and_column(client: TestClient) -> None:
    bad = b"id,ra,dec\na,10,20\nb," + b"1" * 5000 + b",20\n"
    r = _post(client, "cells.csv", bad)
    assert r.status_code == 422
    assert r.json()["detail"][0]["loc"] == ["body", "file"]
    assert "cells.csv: row 2, line 3, column 'ra': a cell of 5000 characters" in r.text


def test_the_row_limit_applies_while_reading(client: TestClient, corpus: dict[str, Attack]) -> None:
    r = _post(client, "rows.csv", corpus["many_rows"].path.read_bytes())
    assert "more than 10000 rows (line 10002)" in r.text  # stopped at the first row over
    assert "MXS_MAX_TARGET_LIST_TARGETS=10000" in r.text
    r = _post(client, "big.fits", corpus["fits_many_rows"].path.read_bytes())
    assert "HDU 1 declares" in r.text and "MXS_MAX_TARGET_LIST_TARGETS=10000" in r.text


# ------------------------------------------------------------------ limits of the reader


def _sexagesimal_csv(n: int) -> bytes:
    rows = (f"t{i},{i % 24:02d}:{i % 60:02d}:{(i * 7) % 60:05.2f},+{i % 80:02d}:{i % 60:02d}:"
            f"{(i * 3) % 60:04.1f}\n" for i in range(n))
    return ("id,ra,dec\n" + "".join(rows)).encode()


def _decimal_csv(n: int) -> bytes:
    return ("id,ra,dec\n" + "".join(f"t{i},{(i * 0.001) % 360!r},{(i * 0.0007) % 80!r}\n"
                                    for i in range(n))).encode()


def test_a_reader_past_the_time_limit_is_stopped_with_a_422(tmp_path: Path) -> None:
    with TestClient(create_app(_settings(tmp_path, upload_parse_time_s=0.05))) as c:
        t0 = time.monotonic()
        r = _post(c, "slow.csv", _sexagesimal_csv(5000))
        assert time.monotonic() - t0 < 5.0
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "file"]
    assert "MXS_UPLOAD_PARSE_TIME_S=0.05" in r.text and "took longer" in r.text


def test_a_reader_past_the_memory_limit_is_stopped_with_a_413(tmp_path: Path) -> None:
    s = _settings(tmp_path, upload_parse_memory_bytes=16_000_000, max_target_list_targets=100_000)
    with TestClient(create_app(s)) as c:
        r = _post(c, "big.csv", _decimal_csv(100_000))  # 3 MB: tens of MB to read
    assert r.status_code == 413, r.text
    assert "MXS_UPLOAD_PARSE_MEMORY_BYTES=16000000" in r.json()["detail"]


# ------------------------------------------------------------------ a served instance


@contextmanager
def serve(settings: Settings) -> Iterator[str]:
    """``create_app(settings)`` served by uvicorn in a thread; yields its URL."""
    import uvicorn

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port,
                                           log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    try:
        yield url
    finally:
        server.should_exit = True
        thread.join(timeout=10)


def _readers() -> list[psutil.Process]:
    """The upload readers: children of this process's fork server."""
    out = []
    for p in psutil.Process().children(recursive=True):
        try:
            if "forkserver" in " ".join(p.cmdline()):
                out += p.children()
        except psutil.Error:
            pass
    return out


def test_health_answers_while_hostile_uploads_are_read(tmp_path: Path,
                                                       corpus: dict[str, Attack]) -> None:
    files = [("dup40k.csv", corpus["duplicate_columns_40kb"].path.read_bytes()),
             ("dup.csv", corpus["duplicate_columns_to_limit"].path.read_bytes()),  # 1M columns
             ("r.csv", corpus["long_ra_cell_30kb"].path.read_bytes()),
             ("slow.csv", _sexagesimal_csv(8000))]
    with serve(_settings(tmp_path)) as url:
        answers: list[int] = []

        def upload(name: str, data: bytes) -> None:
            with httpx.Client(base_url=url, timeout=60) as c:
                answers.append(_post(c, name, data).status_code)

        threads = [threading.Thread(target=upload, args=f) for f in files]
        for t in threads:
            t.start()
        worst_s, probes = 0.0, 0
        with httpx.Client(base_url=url, timeout=10) as c:
            while any(t.is_alive() for t in threads):
                t0 = time.monotonic()
                assert c.get("/v1/health").status_code == 200
                worst_s, probes = max(worst_s, time.monotonic() - t0), probes + 1
                time.sleep(0.01)
    assert sorted(answers) == [200, 422, 422, 422]
    # a frozen server misses probes for seconds; the bound leaves room for the suite's other
    # worker (CP-SAT on two threads) taking both cores for a moment. The latency figure itself
    # is the benchmark's (benchmarks/load.py --attack).
    assert probes >= 5 and worst_s < 1.5, (probes, worst_s)


def test_an_upload_needs_a_free_heavy_slot(tmp_path: Path) -> None:
    with serve(_settings(tmp_path, heavy_threads=1, heavy_queue=0,
                         max_target_list_targets=100_000)) as url:
        first: list[httpx.Response] = []

        def slow() -> None:
            with httpx.Client(base_url=url, timeout=60) as c:
                first.append(_post(c, "slow.csv", _sexagesimal_csv(20_000)))

        t = threading.Thread(target=slow)
        t.start()
        with httpx.Client(base_url=url, timeout=10) as c:
            deadline = time.monotonic() + 20
            while c.get("/v1/health/ready").json()["heavy_in_use"] == 0:
                assert time.monotonic() < deadline
                time.sleep(0.02)
            r = _post(c, "t.csv", b"ra,dec\n1,2\n")
        t.join()
    assert r.status_code == 503 and int(r.headers["retry-after"]) >= 1
    assert first[0].status_code == 200 and first[0].json()["n_targets"] == 20_000


def test_a_client_that_leaves_stops_its_reader(tmp_path: Path) -> None:
    data = _sexagesimal_csv(60_000)  # several seconds of reading
    boundary = "mxsboundary"
    body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; "
            f"filename=\"slow.csv\"\r\nContent-Type: text/csv\r\n\r\n").encode() + data + \
        f"\r\n--{boundary}--\r\n".encode()
    with serve(_settings(tmp_path, max_target_list_targets=100_000)) as url:
        host, port = url.rsplit("/", 1)[1].split(":")
        sock = socket.create_connection((host, int(port)))
        sock.sendall(f"POST /v1/target-lists HTTP/1.1\r\nHost: {host}\r\nContent-Type: "
                     f"multipart/form-data; boundary={boundary}\r\nContent-Length: "
                     f"{len(body)}\r\n\r\n".encode() + body)
        deadline = time.monotonic() + 20
        while not _readers():
            assert time.monotonic() < deadline, "no reader started"
            time.sleep(0.02)
        sock.close()
        left = time.monotonic()
        while _readers():
            assert time.monotonic() - left < 3.0, "the reader outlived its client"
            time.sleep(0.05)


# ------------------------------------------------------------------ valid uploads


def _fits(t: Table) -> bytes:
    buf = io.BytesIO()
    t.write(buf, format="fits")
    return buf.getvalue()


def _ecsv(t: Table) -> bytes:
    buf = io.StringIO()
    t.write(buf, format="ascii.ecsv")
    return buf.getvalue().encode()


TABLE = Table({"id": ["a", "b", "c"], "ra": [10.5, 11.25, 12.0], "dec": [-5.0, 0.5, 30.125],
               "priority": [1, 2, 3]})
VALID = {".fits": lambda: _fits(TABLE), ".fits.gz": lambda: gzip.compress(_fits(TABLE)),
         ".csv": lambda: b"id,ra,dec,priority\na,10.5,-5.0,1\nb,11.25,0.5,2\nc,12.0,30.125,3\n",
         ".csv.bz2": lambda: bz2.compress(VALID[".csv"]()), ".ecsv": lambda: _ecsv(TABLE)}


@pytest.mark.parametrize("suffix", list(VALID))
def test_a_long_name_keeps_its_suffix_and_its_format(client: TestClient, suffix: str) -> None:
    name = "n" * 300 + suffix
    r = client.post("/v1/target-lists", files={"file": (name, VALID[suffix]())})
    assert r.status_code == 200, r.text[:300]
    body = r.json()
    assert body["filename"].endswith(suffix) and len(body["filename"]) <= 200
    got = [(t["id"], t["ra_deg"], t["dec_deg"], t["priority"]) for t in body["targets"]]
    assert got == [("a", 10.5, -5.0, 1), ("b", 11.25, 0.5, 2), ("c", 12.0, 30.125, 3)]


def test_compressed_files_read_as_the_plain_ones(client: TestClient, tmp_path: Path) -> None:
    example = Path(__file__).resolve().parents[1] / "examples" / "ngc869_targets.csv"
    plain = read_targets(example)
    for name, data in (("t.csv.gz", gzip.compress(example.read_bytes())),
                       ("t.csv", bz2.compress(example.read_bytes()))):
        r = client.post("/v1/target-lists", files={"file": (name, data)})
        assert r.status_code == 200, r.text[:300]
        got = [{k: t[k] for k in ("id", "ra_deg", "dec_deg", "priority")} for t in r.json()["targets"]]
        assert got == plain
    big = Table({"ra": np.linspace(10, 11, 5000), "dec": np.linspace(-1, 1, 5000)})
    r = client.post("/v1/target-lists", files={"file": ("t.fits.gz", gzip.compress(_fits(big)))},
                    params={"include_targets": "false"})
    assert r.status_code == 200 and r.json()["n_targets"] == 5000


def test_the_answer_to_an_upload_is_the_stored_list(client: TestClient) -> None:
    data = b"id,ra,dec\na,10.5,-5\nb,16:41:41.7,+36:27:41\nc,1e1,-0.5\n"
    answers = {}
    for include in ("true", "false"):
        r = client.post("/v1/target-lists", files={"file": ("\u00e9t\u00e9.csv", data)},
                        params={"include_targets": include})
        assert r.status_code == 200 and r.headers["content-type"] == "application/json"
        got = client.get(f"/v1/target-lists/{r.json()['target_list_id']}",
                         params={"include_targets": include})
        assert r.content == got.content  # byte for byte, as GET writes it
        answers[include] = r.json()
    assert [(t["row"], t["line"]) for t in answers["true"]["targets"]] == [(1, 2), (2, 3), (3, 4)]
    assert answers["false"]["targets"] == [] and answers["false"]["n_targets"] == 3
