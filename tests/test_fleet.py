"""fleet: a directory of records identified on Dask, one Parquet row per record. Oracles: the
same identifier's plain batched call on the same records (numpy), pyarrow's reading of the
table; a worker killed mid-run (a local cluster's nanny restarts it) and a resumed run."""

import os
import shutil
import signal

# the fleet extra is part of the dev install the suite runs under: a missing one fails here
# instead of skipping the module
import dask.distributed  # noqa: F401
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import threadpoolctl
import torch

import aeid_struct as ae
from aeid_struct.cli import main
from aeid_struct.fleet import SCHEMA, chunks, identify_many


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """A source of 1,300 leg-stable step responses in three formats, one record not finite,
    one file that is no array; and the plain batched estimates of the good files."""
    src = tmp_path_factory.mktemp("fleet")
    ident = ae.load("leg-stable")
    rec = ae.data.records(ae.LegFamily(subsystem="stable"), 1300, steps=ident.steps,
                          dt=ident.dt, seed=4, noise=0.01)
    np.save(src / "a.npy", rec.y[:900])
    y = rec.y[900:1200].copy()
    y[3, 7] = np.nan
    (src / "more").mkdir()
    np.savez(src / "more" / "b.npz", y=y)
    pq.write_table(pa.table({"y": [list(r) for r in rec.y[1200:]]}), src / "c.parquet")
    (src / "bad.npy").write_bytes(b"not an array")
    # the plain call as the workers run it: Dask's nanny gives each worker process one OpenMP
    # and BLAS thread, and on some BLAS kernels the float32 encoder's sums are blocked by the
    # thread count (two threads against one: 1e-7 apart on OpenBLAS's SkylakeX kernel)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with threadpoolctl.threadpool_limits(1):
            plain = ident.identify(rec.y, errors="collect")
    finally:
        torch.set_num_threads(threads)
    return src, plain


def _table(out) -> pd.DataFrame:
    return pd.read_parquet(out).set_index("record").sort_index()


def _check(table: pd.DataFrame, plain) -> None:
    assert len(table) == 1301
    assert table.loc["bad.npy#0", "status"] == "refused"
    assert "bad.npy cannot be read as records" in table.loc["bad.npy#0", "reason"]
    assert table.loc["more/b.npz#3", "status"] == "refused"
    assert "must be finite" in table.loc["more/b.npz#3", "reason"]
    assert (table.status == "ok").sum() == 1299
    for name, k in [("a.npy#0", 0), ("a.npy#899", 899), ("more/b.npz#4", 904),
                    ("c.parquet#99", 1299)]:
        row = table.loc[name]
        assert (row.n, row.m, row.p) == (2, 1, 1)
        np.testing.assert_allclose(np.reshape(row.A, (2, 2)), plain.A[k], rtol=1e-12)
        np.testing.assert_allclose(row.C, plain.c[k], rtol=1e-12)
        assert row.fit == pytest.approx(plain.fit[k], rel=1e-12)
        assert bool(row.outside) == bool(plain.outside[k])


def test_chunks_cover_every_record_in_a_stable_order(fleet):
    src, _ = fleet
    cs = chunks(src, chunk=400)
    assert [c.key for c in cs] == ["a.npy@0", "a.npy@400", "a.npy@800", "bad.npy@0",
                                   "c.parquet@0", "more/b.npz@0"]
    assert [(c.start, c.stop) for c in cs] == [(0, 400), (400, 800), (800, 900), (0, None),
                                               (0, 100), (0, 300)]
    with pytest.raises(ValueError, match="chunk must be an integer >= 1"):
        chunks(src, chunk=0)
    empty = src.parent / "empty"
    empty.mkdir(exist_ok=True)
    with pytest.raises(ValueError, match="holds no record files"):
        chunks(empty, chunk=10)


def test_identify_many_is_the_plain_loop_and_resumes(fleet, tmp_path):
    src, plain = fleet
    out = tmp_path / "results.parquet"
    run = identify_many(src, "leg-stable", out, workers=2, chunk=400, progress=None)
    assert (run.chunks, run.skipped, run.records, run.ok) == (6, 0, 1301, 1299)
    table = _table(out)
    _check(table, plain)
    meta = pq.read_schema(next(out.glob("part-a.npy@0*"))).metadata[b"aeid"]
    assert f'"schema": {SCHEMA}'.encode() in meta and b'"a0"' in meta
    # resumed: a lost part is the only work of the next run, and the table is the same
    os.remove(next(out.glob("part-a.npy@400*")))
    again = identify_many(src, "leg-stable", out, workers=1, chunk=400, progress=None)
    assert (again.skipped, again.records) == (5, 400)
    pd.testing.assert_frame_equal(_table(out), table)


def test_a_worker_killed_mid_run_loses_nothing(fleet, tmp_path):
    """A local cluster of two nannied workers, reached by its address (the test's own client,
    which reads the workers' process ids, is the one identify_many uses); when the first chunk
    is done one worker's process is killed (SIGKILL): its tasks run again elsewhere and every
    record gets its row."""
    from dask.distributed import Client, LocalCluster

    src, plain = fleet
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        killed = []

        pids = client.run(os.getpid)

        def kill_one(line):
            if not killed:
                victim = sorted(pids)[0]
                killed.append(victim)
                os.kill(pids[victim], signal.SIGKILL)

        run = identify_many(src, "leg-stable", tmp_path / "out",
                            scheduler=cluster.scheduler_address, chunk=100, progress=kill_one)
    assert killed and run.records == 1301
    _check(_table(tmp_path / "out"), plain)


def test_identify_many_refuses_what_it_cannot_run(fleet, tmp_path, monkeypatch):
    from aeid_struct.fleet import many

    monkeypatch.setattr(many, "CONNECT_TIMEOUT", "2s")      # a closed port answers nothing
    src, _ = fleet
    with pytest.raises(ValueError, match="a generic identifier"):
        identify_many(src, "generic-2", tmp_path / "o", progress=None)
    with pytest.raises(ValueError, match="neither a directory nor a file"):
        identify_many(tmp_path / "none", "leg-stable", tmp_path / "o", progress=None)
    with pytest.raises(ValueError, match="workers must be an integer"):
        identify_many(src, "leg-stable", tmp_path / "o", workers=0, progress=None)
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="out must be a directory"):
        identify_many(src, "leg-stable", tmp_path / "file", progress=None)
    with pytest.raises(ValueError, match="scheduler 'tcp://127.0.0.1:9': no Dask scheduler"):
        identify_many(src, "leg-stable", tmp_path / "o", scheduler="tcp://127.0.0.1:9",
                      progress=None)


def test_cli_identify_many(fleet, tmp_path, capsys):
    src, plain = fleet
    out = tmp_path / "cli.parquet"
    assert main(["identify-many", str(src), "--identifier", "leg-stable", "--out", str(out),
                 "--workers", "2", "--chunk", "500", "--quiet"]) == 0
    assert "1301 records identified (1299 with a model, 2 refused" in capsys.readouterr().out
    _check(_table(out), plain)
    with pytest.raises(SystemExit):
        main(["identify-many", str(src), "--identifier", "generic-2", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "identify-many: identifier 'generic-2'" in err[0]
    shutil.rmtree(out)


def test_a_file_that_is_not_an_array_is_refused_as_data(tmp_path):
    """Bytes without the .npy or .zip magic (numpy takes them for a pickle and advises loading
    them unsafely): the file is one chunk, and its reason says what it is not, never how to
    unpickle it; an object array keeps numpy's own refusal (read memory-mapped)."""
    from aeid_struct.fleet.sources import read_chunk

    (tmp_path / "garbage.npy").write_bytes(b"not an npy file at all")
    (tmp_path / "garbage.npz").write_bytes(b"nor a zip archive")
    np.save(tmp_path / "object.npy", np.array([1.0, None], dtype=object), allow_pickle=True)
    found = {c.key: c for c in chunks(tmp_path)}
    assert sorted(found) == ["garbage.npy@0", "garbage.npz@0", "object.npy@0"]
    for key in ("garbage.npy@0", "garbage.npz@0"):
        with pytest.raises(ValueError, match=r"cannot be read as records \(ValueError: neither "
                                             r"an .npy array nor an .npz archive: not loaded, "
                                             r"as a pickle never is\)$"):
            read_chunk(found[key])
    with pytest.raises(ValueError, match=r"\(ValueError: Array can't be memory-mapped: Python "
                                         r"objects in dtype.\)$"):
        read_chunk(found["object.npy@0"])


def test_parquet_chunks_read_their_own_row_groups(tmp_path):
    """Chunks that cut across a Parquet file's row groups read exactly their rows (pyarrow's
    table as the oracle), with u where the table has it."""
    from aeid_struct.fleet.sources import read_chunk

    y = np.arange(50 * 4, dtype=float).reshape(50, 4)
    u = -y
    pq.write_table(pa.table({"y": [list(r) for r in y], "u": [list(r) for r in u]}),
                   tmp_path / "t.parquet", row_group_size=7)
    cs = chunks(tmp_path / "t.parquet", chunk=12)
    assert [(c.start, c.stop) for c in cs] == [(0, 12), (12, 24), (24, 36), (36, 48), (48, 50)]
    for c in cs:
        got_y, got_u, dt = read_chunk(c)
        assert dt is None
        np.testing.assert_array_equal(got_y, y[c.start:c.stop])
        np.testing.assert_array_equal(got_u, u[c.start:c.stop])


def test_csv_sources_are_read_as_the_command_line_reads_them(tmp_path):
    """CSV records in the layouts of ``aeid-struct identify`` (records.files): a named-column
    record whose t column is checked against the identifier's dt, a batch of records one per
    line; a record at another dt and a several-channel file are refused by name; the estimates
    are the plain batched call's."""
    ident = ae.load("leg-stable")
    rec = ae.data.records(ae.LegFamily(subsystem="stable"), 4, steps=ident.steps, dt=ident.dt,
                          seed=6, noise=0.01)
    t = np.arange(ident.steps) * ident.dt
    src = tmp_path / "csv"
    src.mkdir()
    np.savetxt(src / "one.csv", np.column_stack([t, rec.y[0]]), delimiter=",",
               header="t [s],y [m]", comments="")
    np.savetxt(src / "batch.csv", rec.y[1:3], delimiter=",")
    np.savetxt(src / "slow.csv", np.column_stack([2 * t, rec.y[3]]), delimiter=",",
               header="t,y", comments="")
    np.savetxt(src / "two.csv", np.column_stack([t, rec.y[0], rec.y[1]]), delimiter=",",
               header="t,y1,y2", comments="")
    np.savetxt(src / "short.csv", rec.y[:3, :50], delimiter=",")       # 3 records, too short
    # a CSV is one chunk its worker parses (nothing read while the source is cut)
    assert [(c.key, c.stop) for c in chunks(src, chunk=1)] == [
        ("batch.csv@0", None), ("one.csv@0", None), ("short.csv@0", None), ("slow.csv@0", None),
        ("two.csv@0", None)]
    out = tmp_path / "csv.parquet"
    run = identify_many(src, "leg-stable", out, workers=1, chunk=10, progress=None)
    assert (run.records, run.ok) == (8, 3)
    table = _table(out)
    # the one-record file takes the batch-1 path, the batch file the batched one, as plainly
    one, batch = ident.identify(rec.y[0]), ident.identify(rec.y[1:3])
    for name, A in [("one.csv#0", one.A), ("batch.csv#0", batch.A[0]),
                    ("batch.csv#1", batch.A[1])]:
        np.testing.assert_allclose(np.reshape(table.loc[name, "A"], (2, 2)), A, rtol=1e-12)
    assert table.loc["slow.csv#0", "status"] == "refused"
    assert "dt" in table.loc["slow.csv#0", "reason"]
    assert "several outputs or inputs" in table.loc["two.csv#0", "reason"]
    # a CSV batch the identifier refuses as a whole: each of its records gets the reason
    assert [table.loc[f"short.csv#{i}", "status"] for i in range(3)] == ["refused"] * 3
    assert "300" in table.loc["short.csv#2", "reason"]


def test_a_part_cut_off_mid_write_leaves_the_table_readable(fleet, tmp_path, monkeypatch):
    """A worker killed while writing its part leaves the temporary file behind: it is hidden,
    so the directory still reads as the table of the finished parts (a visible one made
    pyarrow fail on the whole directory)."""
    import pyarrow.parquet as parquet

    from aeid_struct.fleet import work

    src, _ = fleet
    out = tmp_path / "out"
    out.mkdir()
    first, second = chunks(src, chunk=400)[:2]
    work.identify_chunk("leg-stable", first, out, str(src))

    def dies_mid_write(table, where):
        open(where, "wb").write(b"PAR1 half a part")
        raise KeyboardInterrupt                   # the process ends here

    monkeypatch.setattr(parquet, "write_table", dies_mid_write)
    with pytest.raises(KeyboardInterrupt):
        work.identify_chunk("leg-stable", second, out, str(src))
    left = sorted(p.name for p in out.iterdir())
    assert len(left) == 2 and left[0].startswith(".") and left[1].startswith("part-a.npy@0")
    assert len(_table(out)) == 400


def test_an_identifier_of_ones_own_mechanism_runs_with_its_maps(tmp_path, capsys):
    # --maps: the user's script builds the map again; it reaches every worker (pickled by
    # Dask) and is checked there against the file's SHA-256; the rows are the plain call's
    from helpers import write_machine

    script, path, structure = write_machine(tmp_path)
    ident = ae.load(path, maps={"myplant_y0_u0": structure.function})
    rec = ae.data.records(ae.ParameterFamily(structure), 6, steps=100, dt=0.02,
                          excitation_kind="prbs", seed=2, noise=0.01)
    src = tmp_path / "src"
    src.mkdir()
    np.savez(src / "plants.npz", y=rec.y, u=rec.u)
    with pytest.raises(SystemExit, match="user map 'myplant_y0_u0'.*--maps FILE.py"):
        main(["identify-many", str(src), "--identifier", str(path), "--out",
              str(tmp_path / "none")])
    out = tmp_path / "out"
    assert main(["identify-many", str(src), "--identifier", str(path), "--maps", str(script),
                 "--out", str(out), "--workers", "1", "--chunk", "4", "--quiet"]) == 0
    table = _table(out)
    assert list(table["status"]) == ["ok"] * 6
    plain = ident.identify(rec.y, rec.u)
    np.testing.assert_allclose(np.stack(table["physical"]),
                               np.stack([plain.physical[k] for k in ("m", "k", "d")], 1),
                               rtol=1e-6)
