"""ISIS binary control networks in (versions 2 and 5, ISIS's own test networks), networks out (binary and PVL),
and ``selfcal export isis-cnet`` after an adjustment of the Apollo 15 block."""
import dataclasses
import gzip
import math
import os
import struct

import numpy as np
import pytest

from selfcal.errors import BlockError
from selfcal.io import protobuf as pb
from selfcal.io.isis import read_control_network
from selfcal.io.isis_cnet import LABEL_BYTES, is_binary_network, network_bytes, network_pvl

from conftest import SHARED_DATA, run_cli

HERE = os.path.dirname(os.path.abspath(__file__))
ISIS_NETS = os.path.join(HERE, "data", "isis_binary")
APOLLO = os.path.join(SHARED_DATA, "isis", "apollo15_metric")
LRO = os.path.join(SHARED_DATA, "isis", "lro_nac_pair")
SHARED_NETWORKS = [os.path.join(APOLLO, "apolloNet.pvl"), os.path.join(LRO, "observationPair.net")]


def _unzip(name, tmp_path):
    out = tmp_path / name.removesuffix(".gz")
    with open(os.path.join(ISIS_NETS, name), "rb") as handle:
        out.write_bytes(gzip.decompress(handle.read()))
    return str(out)


def _same(a, b):
    """Every field of two networks' points and measures equal (arrays exactly, NaN equal NaN)."""
    assert (a.network_id, a.target_name, len(a.points)) == (b.network_id, b.target_name, len(b.points))
    for p, q in zip(a.points, b.points):
        for f in dataclasses.fields(p):
            x, y = getattr(p, f.name), getattr(q, f.name)
            if f.name == "source_line":
                continue
            if f.name == "measures":
                assert len(x) == len(y), p.point_id
                for m, n in zip(x, y):
                    for g in dataclasses.fields(m):
                        u, v = getattr(m, g.name), getattr(n, g.name)
                        if g.name == "source_line":
                            continue
                        assert u == v or (isinstance(u, float) and math.isnan(u) and math.isnan(v)), \
                            (p.point_id, g.name, u, v)
            elif isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
                assert x is not None and y is not None and np.array_equal(x, y), (p.point_id, f.name, x, y)
            else:
                assert x == y, (p.point_id, f.name, x, y)


def test_wire_format_round_trips_varints_doubles_and_strings():
    """Varints of 0, 1, 127, 128, 300, 2^32, 2^63 and negative int32s (10 bytes) decode to themselves; a message
    of every wire type decodes field by field at the right offsets; a cut message is an error naming its byte."""
    for value in (0, 1, 127, 128, 300, 2**32, 2**63 - 1, -1, -2**31):
        enc = pb.varint(value)
        got, pos = pb.read_varint(enc, 0, len(enc), "x")
        assert pos == len(enc) and (got - (1 << 64) if got >= 1 << 63 else got) == value
    assert pb.varint(300) == b"\xac\x02" and len(pb.varint(-1)) == 10          # protobuf.dev's examples
    out = bytearray()
    pb.put_string(out, 1, "AS15/ü")
    pb.put_varint(out, 2, 3)
    pb.put_double(out, 16, -1735605.5768747)
    pb.put_packed_doubles(out, 19, [1.0, 0.5, -2.25])
    got = pb.fields(bytes(out), "x", base=100)
    assert [(n, w) for n, w, _, _ in got] == [(1, 2), (2, 0), (16, 1), (19, 2)]
    assert got[0][2].decode() == "AS15/ü" and got[0][3] == 100 and got[1][3] == 100 + 2 + len("AS15/ü".encode())
    assert pb.as_double(got[2][2], 1, "x", 0, "X") == -1735605.5768747
    assert pb.packed_doubles(got[3][2], 2, "x", 0, "c") == [1.0, 0.5, -2.25]
    with pytest.raises(BlockError, match=r"x: byte 1\d\d: field 19 is 24 bytes long, past the end"):
        pb.fields(bytes(out[:-1]), "x", base=100)
    with pytest.raises(BlockError, match=r"byte 5: truncated varint"):
        pb.fields(b"\x08\x80", "x", base=4)


def test_isis_written_binary_networks_read(tmp_path):
    """ISIS's own binary networks: version 5 (THEMIS/Viking, length-prefixed points) and version 2 (Kaguya,
    point sizes in the header). Points and measures are as many as their labels state (25/58 and 54/54), the
    Mars points' a-priori and adjusted radii within 30 km of Mars's 3390 km, the measures at positive
    pixels (22 points have coordinates, 3 hand-added ones none); the v2 network's single measures are each its point's reference (referenceIndex 0)."""
    from selfcal.io.pvl import parse_pvl
    for name, version, n_points, n_measures in (("themis_dayir_VO_arcadia_extract_hand.net.gz", 5, 25, 58),
                                                ("Alph_VIS.net.gz", 2, 54, 54)):
        path = _unzip(name, tmp_path)
        with open(path, "rb") as handle:
            data = handle.read()
        label = parse_pvl(data[:data.index(b"\0")].decode(), path).find("Group", "ControlNetworkInfo")
        assert int(label.keyword("NumberOfPoints").value) == n_points
        assert int(label.keyword("NumberOfMeasures").value) == n_measures
        assert is_binary_network(path)
        net = read_control_network(path)
        assert net.version == version and net.binary
        assert len(net.points) == n_points and len(net.measures) == n_measures
        assert all(m.sample > 0 and m.line > 0 for m in net.measures)
        assert all(p.source_line >= LABEL_BYTES for p in net.points)
        if version == 5:
            assert net.network_id == "themis_vo" and net.target_name == "MARS"
            counts = net.counts()
            assert counts["points_by_type"] == {"Free": 21, "Constrained": 4}
            placed = [p for p in net.points if p.apriori_xyz_m is not None]
            assert len(placed) == 22 and all(p.adjusted_xyz_m is not None for p in placed)   # 3 hand-added: none
            for p in placed:
                for xyz in (p.apriori_xyz_m, p.adjusted_xyz_m):
                    assert abs(np.linalg.norm(xyz) - 3389.5e3) < 30e3, p.point_id
            constrained = [p for p in net.points if p.point_type == "Constrained"]
            assert all(p.apriori_covariance_m2 is not None for p in constrained)
            assert all(np.all(np.linalg.eigvalsh(p.apriori_covariance_m2) > 0) for p in constrained)
        else:
            assert net.network_id == "THM_IMG_NET" and all(p.measures[0].reference for p in net.points)
            assert {m.measure_type for m in net.measures} == {"Candidate"}
        _same(net, read_control_network(_write_bytes(tmp_path / "again.net", network_bytes(net))))


def _write_bytes(path, data):
    path.write_bytes(data)
    return str(path)


@pytest.mark.parametrize("source", SHARED_NETWORKS, ids=["apollo", "lro"])
def test_real_pvl_networks_round_trip_binary_and_pvl(source, tmp_path):
    """apolloNet.pvl (395 points, 969 measures) and observationPair.net (46 points): PVL -> binary -> read and
    PVL -> PVL -> read give every field of every point and measure as read from the original (exactly); the
    binary is ISIS's layout (label in the first 64 KiB, header at 65536, little-endian length before each
    point, the lengths adding up to PointsBytes)."""
    net = read_control_network(source)
    data = network_bytes(net)
    binary = _write_bytes(tmp_path / "net.pvl", data)           # a binary named .pvl: read by its content
    again = read_control_network(binary)
    assert again.binary and again.version == 5
    _same(net, again)
    text = tmp_path / "net.bin"
    text.write_text(network_pvl(net))
    assert not is_binary_network(str(text))
    _same(net, read_control_network(str(text)))
    from selfcal.io.pvl import parse_pvl
    core = parse_pvl(data[:data.index(b"\0")].decode(), "x").find("Object", "Core")
    start, size = int(core.keyword("HeaderStartByte").value), int(core.keyword("HeaderBytes").value)
    pos, end, n = start + size, start + size + int(core.keyword("PointsBytes").value), 0
    assert start == LABEL_BYTES and end == len(data)
    while pos < end:
        pos += 4 + struct.unpack("<I", data[pos:pos + 4])[0]
        n += 1
    assert pos == end and n == len(net.points)


def test_damaged_binary_networks_are_errors_naming_the_byte(tmp_path):
    """A truncated file, a damaged point length and a point without its id: BlockError naming the file and the
    byte offset; `selfcal import isis` of the truncated one exits 2."""
    net = read_control_network(SHARED_NETWORKS[1])
    data = network_bytes(net)
    cut = _write_bytes(tmp_path / "cut.net", data[:-10])
    with pytest.raises(BlockError, match=r"cut\.net: byte 65\d+: the points .* run past the end of the file"):
        read_control_network(cut)
    header = int(data[:LABEL_BYTES].split(b"HeaderBytes     = ")[1].split(b"\n")[0])
    at = LABEL_BYTES + header
    bad = bytearray(data)
    bad[at:at + 4] = struct.pack("<I", 10**8)
    with pytest.raises(BlockError, match=rf"bad\.net: byte {at}: bad point length 100000000"):
        read_control_network(_write_bytes(tmp_path / "bad.net", bytes(bad)))
    no_id = bytearray(data)
    no_id[at + 4] = (3 << 3) | 2                 # the id field (1) renamed chooserName (3): no id left
    with pytest.raises(BlockError, match=rf"byte {at + 4}: a point has no id"):
        read_control_network(_write_bytes(tmp_path / "noid.net", bytes(no_id)))
    assert run_cli("import", "isis", cut, "--images", LRO, "--out", str(tmp_path / "blk")) == 2
    assert not os.path.exists(tmp_path / "blk")


# --- export isis-cnet after an adjustment of the Apollo 15 block ---------------------------------------------

@pytest.fixture(scope="module")
def apollo_export(tmp_path_factory):
    """Import apolloNet.pvl, adjust (jigsaw's settings: no snooping, no robust cleaning), export the network as PVL and binary."""
    tmp = tmp_path_factory.mktemp("apollo_export")
    net = os.path.join(APOLLO, "apolloNet.pvl")
    assert run_cli("import", "isis", net, "--images", APOLLO, "--out", str(tmp / "block"),
                   "--sigma-position-m", "1000", "--sigma-attitude-deg", "2") == 0
    assert run_cli("adjust", str(tmp / "block"), "--out", str(tmp / "res"), "--no-report", "--snoop", "0",
                   "--robust", "none") == 0
    for flag, name in (((), "onet.pvl"), (("--binary",), "onet.net")):
        assert run_cli("export", "isis-cnet", str(tmp / "res"), "--network", net, "--images", APOLLO,
                       "--out", str(tmp / name), *flag) == 0
    return tmp


def test_exported_network_holds_the_adjusted_points_and_residuals(apollo_export):
    """Both exports re-read (the PVL one by the PVL reader, the binary one by the binary reader): every point's
    AdjustedX/Y/Z is points.csv's X, Y, Z (1e-6 m), every measure's SampleResidual/LineResidual is -vx, vy of
    residuals.csv times 4 (detector pixels of the cubes reduced 4x; 1e-6 px), the a-priori values and measures
    as imported; the residuals are jigsaw's in sense and unit (measured - computed, detector pixels):
    EXPECTED_VALUES' four spot-checked measures agree with jigsaw's within 0.05 px (measured: within 0.0003 px, the CSV's 4 decimals times 4)."""
    from selfcal.io.results import read_results_table
    tmp = apollo_export
    points = read_results_table(tmp / "res", "points.csv")
    res = read_results_table(tmp / "res", "residuals.csv")
    original = read_control_network(os.path.join(APOLLO, "apolloNet.pvl"))
    xyz = {pid: np.array([points[a][k] for a in "XYZ"]) for k, pid in enumerate(points["point_id"])}
    v = {(str(i), str(p)): (res["vx_px"][k], res["vy_px"][k]) for k, (i, p) in enumerate(zip(res["image_id"],
                                                                                          res["point_id"]))}
    from selfcal.io.isis import read_image_folder
    image = {s: os.path.splitext(os.path.basename(f))[0] for s, (_, f) in read_image_folder(APOLLO).items()}
    for name, binary in (("onet.pvl", False), ("onet.net", True)):
        out = read_control_network(tmp / name)
        assert out.binary == binary and len(out.points) == 395 == len(xyz)
        n = 0
        for p, q in zip(original.points, out.points):
            assert p.point_id == q.point_id and np.array_equal(p.apriori_xyz_m, q.apriori_xyz_m)
            np.testing.assert_allclose(q.adjusted_xyz_m, xyz[q.point_id], rtol=0, atol=1e-6)
            for m, mq in zip(p.measures, q.measures):
                assert (m.sample, m.line, m.serial_number) == (mq.sample, mq.line, mq.serial_number)
                vx, vy = v[(image[m.serial_number], p.point_id)]
                assert abs(mq.sample_residual_px + 4 * vx) < 1e-6 and abs(mq.line_residual_px - 4 * vy) < 1e-6
                assert not mq.rejected and not mq.ignored
                n += 1
        assert n == 969
        by = {(m.point_id, m.serial_number): m for m in out.measures}
        for pid, cube, s_res, l_res in (("AS15_000031448", 1, -0.00343037, 0.70304475),
                                        ("AS15_000032200", 2, -0.00372339, 0.48459119),
                                        ("AS15_000055094", 1, 0.00691807, -0.57578535),
                                        ("AS15_test01", 3, -3.07166713, 1.44947971)):
            serial = next(s for s, i in image.items() if i == f"apolloImage{cube}")
            m = by[(pid, serial)]
            assert abs(m.sample_residual_px - s_res) < 0.05 and abs(m.line_residual_px - l_res) < 0.05, \
                (pid, m.sample_residual_px, m.line_residual_px, s_res, l_res)


def test_exported_binary_network_reimports_the_block(apollo_export, tmp_path):
    """`selfcal import isis` of the exported binary network gives the block the PVL network gave: the same
    images, points (ids, roles, a-priori XYZ and sigmas) and observations (pixels)."""
    from selfcal.io import read_block
    tmp = apollo_export
    assert run_cli("import", "isis", str(tmp / "onet.net"), "--images", APOLLO, "--out", str(tmp_path / "again"),
                   "--sigma-position-m", "1000", "--sigma-attitude-deg", "2") == 0
    a, b = read_block(tmp / "block"), read_block(tmp_path / "again")
    assert list(a.images.image_id) == list(b.images.image_id)
    assert list(a.points.point_id) == list(b.points.point_id) and list(a.points.role) == list(b.points.role)
    np.testing.assert_array_equal(a.points.xyz_m, b.points.xyz_m)
    np.testing.assert_array_equal(a.points.sigma_m, b.points.sigma_m)
    np.testing.assert_array_equal(a.observations.pixel, b.observations.pixel)
    np.testing.assert_array_equal(a.observations.point_index, b.observations.point_index)


def test_rejected_measures_are_marked_jigsaw_rejected(apollo_export):
    """The measures residuals.csv marks rejected (here every fifth, set in a copy of the table) come out
    JigsawRejected with their residuals, not Ignore (jigsaw's outlier rejection); the others stay accepted;
    points the results lack keep the network's own values."""
    from selfcal.convert import adjusted_network
    from selfcal.io.isis import read_image_folder
    from selfcal.io.results import read_results_table
    tmp = apollo_export
    points = read_results_table(tmp / "res", "points.csv")
    res = dict(read_results_table(tmp / "res", "residuals.csv"))
    res["rejected"] = (np.arange(len(res["rejected"])) % 5 == 0).astype(int)
    keep = np.ones(len(points["point_id"]), bool)
    keep[:3] = False
    points = {k: np.asarray(v)[keep] for k, v in points.items()}
    image = {s: os.path.splitext(os.path.basename(f))[0] for s, (_, f) in read_image_folder(APOLLO).items()}
    original = read_control_network(os.path.join(APOLLO, "apolloNet.pvl"))
    net, counts = adjusted_network(original, image, points, res)
    back = read_control_network(_write_bytes(tmp / "rej.net", network_bytes(net)))
    flagged = {(str(i), str(p)) for i, p, r in zip(res["image_id"], res["point_id"], res["rejected"]) if r}
    dropped = set(str(p) for p in np.asarray(read_results_table(tmp / "res", "points.csv")["point_id"])[:3])
    n_rejected = 0
    for p, q in zip(original.points, back.points):
        if p.point_id in dropped:
            assert np.array_equal(p.adjusted_xyz_m, q.adjusted_xyz_m) and all(
                m.sample_residual_px == n.sample_residual_px for m, n in zip(p.measures, q.measures))
            continue
        for m in q.measures:
            assert m.rejected == ((image[m.serial_number], p.point_id) in flagged) and not m.ignored
            n_rejected += m.rejected
    assert n_rejected == counts["measures_rejected"] > 150 and counts["points_adjusted"] == 392
