"""Other splat files (reconstruct.gaussian_files, compressed_ply, spz, splat_file) checked against
PlayCanvas's splat-transform, which bundles Niantic's own .spz library.

``tests/data/splats`` was made by ``scripts/make_splat_fixtures.py``: a 300-Gaussian 3DGS PLY with
degree-1 SH, converted by splat-transform to SuperSplat's compressed PLY and to .spz versions 4
(zstd) and 3 (gzip), and written as .splat by our encoder; splat-transform then decoded each back
to a plain PLY; it also wrote the source as SOG (WebP images and meta.json in a zip). Our reading
of each file must equal splat-transform's decoding (float32 rounding), SH included (SOG: the degree),
and the source within each format's quantisation.
"""

from __future__ import annotations

import gzip
import struct
from pathlib import Path

import numpy as np
import pytest

from reconstruct.compressed_ply import decode_compressed_ply, encode_compressed_ply
from reconstruct.gaussian_files import read_gaussians
from reconstruct.ply import PlyFormatError, _parse_header, _vertex_table, read_gaussians_ply
from reconstruct.sog import decode_sog, encode_sog
from reconstruct.splat_file import decode_splat, encode_splat
from reconstruct.spz import decode_spz, encode_spz

DATA = Path(__file__).parent / "data" / "splats"
FILES = ["source.compressed.ply", "source.spz", "source_v3.spz", "source.splat", "source.sog"]
# each format's quantisation against the source: position (m), log-scale, rotation, opacity, colour
STEPS = {"source.compressed.ply": (1e-3, 2e-3, 2e-3, 3e-3, 3e-3), "source.spz": (3e-4, 0.032, 2e-3, 3e-3, 5e-3),
         "source_v3.spz": (3e-4, 0.032, 2e-3, 3e-3, 5e-3), "source.splat": (1e-6, 1e-6, 8e-3, 3e-3, 3e-3),
         "source.sog": (1e-4, 0.01, 0.012, 5e-3, 3e-3)}


def _columns(path: Path) -> dict[str, np.ndarray]:
    data = path.read_bytes()
    if path.suffix == ".spz":
        return decode_spz(data, path)[0]
    if path.suffix == ".splat":
        return decode_splat(data, path)
    if path.suffix == ".sog":
        return decode_sog(path)[0]
    header = _parse_header(data, path)
    cols, _ = _vertex_table(data, header, path)
    return decode_compressed_ply(data, header, cols, path) if "packed_position" in cols else cols


def _rot_diff(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.minimum(np.abs(a - b).max(1), np.abs(a + b).max(1)).max())


@pytest.mark.parametrize("name", FILES)
def test_each_format_reads_as_splat_transform_decodes_it(name):
    ours = read_gaussians(DATA / name)
    ref = read_gaussians_ply(DATA / (name.replace(".", "_") + ".decoded.ply"))
    assert len(ours) == len(ref) == 300
    assert ours.sh_degree == (0 if name.endswith(".splat") else 1) == ref.sh_degree
    np.testing.assert_allclose(ours.means, ref.means, atol=1e-7)
    np.testing.assert_allclose(np.log(ours.scales), np.log(ref.scales), atol=1e-6)
    assert _rot_diff(ours.rotations.astype(float), ref.rotations.astype(float)) < 1e-6
    np.testing.assert_allclose(ours.opacities, ref.opacities, atol=1e-6)
    np.testing.assert_allclose(ours.colors, ref.colors, atol=1e-6)
    cols, ref_cols = _columns(DATA / name), _columns(DATA / (name.replace(".", "_") + ".decoded.ply"))
    for k in range(9 if name.endswith((".ply", ".spz")) else 0):  # the SH, channel order included (SOG: degree only)
        np.testing.assert_allclose(cols[f"f_rest_{k}"], ref_cols[f"f_rest_{k}"], atol=1e-6, err_msg=f"f_rest_{k}")


@pytest.mark.parametrize("name", FILES)
def test_each_format_holds_the_source_within_its_quantisation(name):
    """The compressed PLY is in Morton order: Gaussians are matched by position first."""
    src, ours = read_gaussians_ply(DATA / "source.ply"), read_gaussians(DATA / name)
    d = np.linalg.norm(ours.means[:, None].astype(float) - src.means[None].astype(float), axis=-1)
    j = d.argmin(1)
    assert len(set(j)) == len(src)
    pos, logscale, rot, opacity, colour = STEPS[name]
    assert d.min(1).max() < pos
    assert np.abs(np.log(ours.scales) - np.log(src.scales[j])).max() < logscale
    assert _rot_diff(ours.rotations.astype(float), src.rotations[j].astype(float)) < rot
    assert np.abs(ours.opacities - src.opacities[j]).max() < opacity
    assert np.abs(ours.colors - np.clip(src.colors[j], 0, 1)).max() < colour
    if name.endswith(".spz") or name.endswith(".ply"):
        src_cols, cols = _columns(DATA / "source.ply"), _columns(DATA / name)
        for k in range(9):
            assert np.abs(cols[f"f_rest_{k}"] - src_cols[f"f_rest_{k}"][j]).max() < 0.035, k


WRITTEN = {"ours.compressed.ply": lambda *a: encode_compressed_ply(*a), "ours_v3.spz": lambda *a: encode_spz(*a, version=3),
           "ours_v4.spz": lambda *a: encode_spz(*a, version=4), "ours.sog": lambda *a: encode_sog(*a)}


@pytest.mark.parametrize("name", sorted(WRITTEN))
def test_our_writers_files_are_read_by_splat_transform_as_the_source(name, tmp_path):
    """What our encoders write today reads as the stored file does; splat-transform (Niantic's
    library for .spz) decoded the stored file to the source within the format's quantisation, and
    our reader reads it exactly as splat-transform does."""
    src = read_gaussians_ply(DATA / "source.ply")
    fresh = WRITTEN[name](src.means, src.scales, src.rotations, src.opacities, src.colors)
    p = DATA / name
    if name.endswith(".sog"):  # the WebP encoder's bytes may change with its version, the texels may not
        (tmp_path / "fresh.sog").write_bytes(fresh)
        cols_now = decode_sog(tmp_path / "fresh.sog")[0]
    else:
        cols_now = decode_spz(fresh, Path("fresh.spz"))[0] if name.endswith(".spz") else None
    if cols_now is not None:
        stored = (decode_sog(p) if name.endswith(".sog") else decode_spz(p.read_bytes(), p))[0]
        for k, v in stored.items():
            np.testing.assert_array_equal(cols_now[k], v, err_msg=k)
    else:
        assert fresh == p.read_bytes()
    theirs = read_gaussians_ply(DATA / (name.replace(".", "_") + ".decoded.ply"))
    ours = read_gaussians(p)
    np.testing.assert_allclose(ours.means, theirs.means, atol=1e-7)
    np.testing.assert_allclose(ours.opacities, theirs.opacities, atol=1e-6)
    np.testing.assert_allclose(ours.colors, theirs.colors, atol=1e-6)
    assert _rot_diff(ours.rotations.astype(float), theirs.rotations.astype(float)) < 1e-6
    d = np.linalg.norm(theirs.means[:, None].astype(float) - src.means[None].astype(float), axis=-1)
    j = d.argmin(1)
    assert len(set(j)) == len(src) and d.min(1).max() < 6e-4
    assert np.abs(np.log(theirs.scales) - np.log(src.scales[j])).max() < 0.032
    # rotations: 10-bit components (compressed PLY, .spz), 8-bit (.sog)
    assert _rot_diff(theirs.rotations.astype(float), src.rotations[j].astype(float)) < (6e-3 if name.endswith(".sog") else 2e-3)
    assert np.abs(theirs.opacities - src.opacities[j]).max() < 2.5e-3
    assert np.abs(theirs.colors - np.clip(src.colors[j], 0, 1)).max() < 4e-3


def test_the_splat_writer_is_what_the_fixture_holds_and_round_trips():
    src = read_gaussians_ply(DATA / "source.ply")
    data = encode_splat(src.means, src.scales, src.rotations, src.opacities, src.colors)
    assert data == (DATA / "source.splat").read_bytes()


def test_spz_comments_and_the_studios_reader(tmp_path):
    assert read_gaussians(DATA / "source.spz").comments == ("spz version 4",)
    assert read_gaussians(DATA / "source_v3.spz").comments == ("spz version 3",)
    assert read_gaussians(DATA / "source.sog").comments == ("sog version 2",)
    import zipfile

    with zipfile.ZipFile(DATA / "source.sog") as z:  # the folder form: meta.json beside its images
        z.extractall(tmp_path / "sog")
    folder = read_gaussians(tmp_path / "sog" / "meta.json")
    np.testing.assert_array_equal(folder.means, read_gaussians(DATA / "source.sog").means)
    from app.studio.ply_source import read_ply_for_view

    for name in FILES:
        info = read_ply_for_view(DATA / name)
        assert info.num_gaussians == 300 and info.snapshot.means.shape == (300, 3)


def test_broken_files_are_refused_naming_the_file(tmp_path):
    def refused(name: str, data: bytes, pattern: str):
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(PlyFormatError, match=pattern):
            read_gaussians(p)

    splat = (DATA / "source.splat").read_bytes()
    refused("cut.splat", splat[:-5], r"cut\.splat: not a \.splat file: its size \(9595 bytes\) is not a positive "
                                     r"multiple of 32")
    refused("empty.splat", b"", r"empty\.splat: not a \.splat file")
    zero = bytearray(splat[:32])
    zero[12:16] = struct.pack("<f", 0.0)
    refused("zero.splat", bytes(zero), r"zero\.splat: 1 Gaussians have a scale that is not a positive finite number")
    spz4 = (DATA / "source.spz").read_bytes()
    refused("cut.spz", spz4[:len(spz4) // 2], r"cut\.spz: \.spz stream \d+: .* expected \d+ within the file's")
    refused("v9.spz", spz4[:4] + struct.pack("<I", 9) + spz4[8:], r"v9\.spz: \.spz version 9; versions 2, 3 and 4")
    v3 = gzip.decompress((DATA / "source_v3.spz").read_bytes())
    refused("short.spz", gzip.compress(v3[:200]), r"short\.spz: truncated \.spz data: 300 Gaussians need \d+ bytes")
    refused("bad.spz", b"\x1f\x8b" + bytes(30), r"bad\.spz: a \.spz file whose gzip stream cannot be unpacked")
    huge = bytearray(v3[:16])
    huge[8:12] = struct.pack("<I", 1 << 30)
    refused("huge.spz", gzip.compress(bytes(huge)), r"huge\.spz: 1073741824 Gaussians declared")
    comp = (DATA / "source.compressed.ply").read_bytes()
    refused("chunks.compressed.ply", comp.replace(b"element chunk 2", b"element chunk 1", 1),
            r"chunks\.compressed\.ply: 300 Gaussians need 2 chunk rows of 256, the file holds 1")
    refused("nochunk.ply", comp.replace(b"element chunk 2", b"element chonk 2", 1),
            r"nochunk\.ply: a compressed PLY needs a 'chunk' element")
    refused("other.bin", b"GIF89a" + bytes(40), r"other\.bin: not a Gaussian splat file this program reads")
    import io
    import json
    import zipfile

    def sog(name: str, change) -> bytes:
        """source.sog with its meta.json changed by ``change(meta)`` (a member left out when it returns a name)."""
        buf = io.BytesIO()
        with zipfile.ZipFile(DATA / "source.sog") as src, zipfile.ZipFile(buf, "w") as dst:
            meta = json.loads(src.read("meta.json"))
            drop = change(meta)
            for info in src.infolist():
                if info.filename == "meta.json":
                    dst.writestr("meta.json", json.dumps(meta))
                elif info.filename != drop:
                    dst.writestr(info, src.read(info))
        return buf.getvalue()

    refused("v1.sog", sog("v1", lambda m: m.pop("version")), r"v1\.sog: SOG version None; version 2")
    refused("noquats.sog", sog("nq", lambda m: "quats.webp"), r"noquats\.sog: the archive has no 'quats\.webp'")
    refused("many.sog", sog("many", lambda m: m.update(count=5000)),
            r"many\.sog: 'means_l\.webp' holds \d+ texels, fewer than the 5000 Gaussians")
    refused("book.sog", sog("book", lambda m: m["scales"].update(codebook=[0.0] * 10)),
            r"book\.sog: meta.json scales\.codebook must hold 256 finite numbers")
    refused("notzip.sog", b"PK\x03\x04" + bytes(40), r"notzip\.sog: not a \.sog archive")
    folder = tmp_path / "outside"
    folder.mkdir()
    with zipfile.ZipFile(DATA / "source.sog") as z:
        meta = json.loads(z.read("meta.json"))
    meta["means"]["files"] = ["../secret.webp", "means_u.webp"]
    (folder / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(PlyFormatError, match=r"meta\.json: meta\.json names '\.\./secret\.webp', outside its folder"):
        read_gaussians(folder / "meta.json")


def test_an_infinite_opacity_logit_is_opacity_one_and_nan_is_refused(tmp_path):
    """splat-transform decodes a compressed PLY's opacity byte 255 (what it and we write for
    opacity 1) to a logit of +inf: such a PLY reads as opacity 1 (-inf as 0); NaN is refused."""
    data = (DATA / "source.ply").read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    table = np.frombuffer(data[end:], "<f4").reshape(300, 23).copy()
    table[0, 15], table[1, 15] = np.inf, -np.inf  # opacity is the 16th property
    p = tmp_path / "inf.ply"
    p.write_bytes(data[:end] + table.tobytes())
    g = read_gaussians(p)
    assert g.opacities[0] == 1.0 and g.opacities[1] == 0.0 and np.all(np.isfinite(g.opacities))
    table[2, 15] = np.nan
    p.write_bytes(data[:end] + table.tobytes())
    with pytest.raises(PlyFormatError, match=r"inf\.ply: non-finite values \(NaN or inf\) in vertex properties "
                                             r"\{'opacity': 1\}"):
        read_gaussians(p)


def test_a_version_2_spz_reads_like_version_3():
    """splat-transform writes only versions 3-4; a version 2 file (rotations as x, y, z bytes with
    w >= 0 derived, as Niantic's first release wrote them) is built here from the version 3 file's
    columns and reads to the same Gaussians: x, y, z within half an 8-bit step, w from them."""
    v3 = gzip.decompress((DATA / "source_v3.spz").read_bytes())
    n = struct.unpack_from("<I", v3, 8)[0]
    sizes = [n * 9, n, n * 3, n * 3]
    head = 16 + sum(sizes)
    ref = read_gaussians(DATA / "source_v3.spz")
    q = ref.rotations.astype(np.float64)
    q = q * np.where(q[:, :1] < 0, -1.0, 1.0)  # w >= 0
    xyz = np.clip(np.round((q[:, 1:] + 1.0) * 127.5), 0, 255).astype(np.uint8)
    v2 = bytearray(v3[:head]) + xyz.tobytes()
    v2[4:8] = struct.pack("<I", 2)
    v2[12] = 0  # no SH columns in this one
    cols, comments = decode_spz(gzip.compress(bytes(v2)), Path("v2.spz"))
    assert comments == ("spz version 2",)
    ours = np.stack([cols[f"rot_{k}"] for k in range(4)], 1)
    assert np.abs(ours[:, 1:] - q[:, 1:]).max() <= 0.5 / 127.5 + 1e-9  # x, y, z within half a step
    np.testing.assert_allclose(ours[:, 0], np.sqrt(np.maximum(0.0, 1.0 - (ours[:, 1:] ** 2).sum(1))))  # w derived
    np.testing.assert_array_equal(np.stack([cols[a] for a in "xyz"], 1).astype(np.float32), ref.means)
