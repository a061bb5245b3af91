#!/usr/bin/env python3
"""Compare the golden outputs of two builds where the newer one adds file identities (issue 41).

    tools/golden/compare_identity.py OLD_DIR NEW_DIR

For every output file present in both trees (the .penumbra/ bookkeeping left out):
- EXR: the headers must hold the same attributes except the new `penumbraIdentity`; every
  offset of the new offset table must be the old one plus the header's growth; and every byte
  after the offset table (the pixel blocks) must be identical. So the samples are the same bits.
- .fhm: the fields of the fixed header must agree (version 1 -> 2, header length + 64), the
  group descriptors and the payload must be identical; only the identity (bytes 48..128) and
  the checksum differ.
- tileset.json: parsed, equal once format_version and the run keys (which hash the format
  versions) are set aside and the Fourier `bytes_per_tile` is taken 64 bytes (the header's
  growth) down.
- anything else (PNGs): byte-identical.
Exit 1 on any other difference; prints a summary.
"""
import json
import os
import struct
import sys


def exr_header_end(b):
    """(attributes {name: (type, bytes)}, offset just after the header's terminating null)."""
    assert b[:4] == b"\x76\x2f\x31\x01", "not an EXR"
    i = 8
    attrs = {}
    while b[i] != 0:
        j = b.index(b"\0", i)
        name = b[i:j].decode()
        k = b.index(b"\0", j + 1)
        typ = b[j + 1 : k].decode()
        (size,) = struct.unpack_from("<i", b, k + 1)
        attrs[name] = (typ, b[k + 5 : k + 5 + size])
        i = k + 5 + size
    return attrs, i + 1


def compare_exr(old, new):
    ao, eo = exr_header_end(old)
    an, en = exr_header_end(new)
    ident = an.pop("penumbraIdentity", None)
    if ident is None:
        return "new file has no penumbraIdentity attribute"
    if ao != an:
        return f"header attributes differ: {set(ao) ^ set(an)}"
    delta = en - eo
    (first,) = struct.unpack_from("<Q", old, eo)
    n = (first - eo) // 8
    offs_o = struct.unpack_from(f"<{n}Q", old, eo)
    offs_n = struct.unpack_from(f"<{n}Q", new, en)
    if any(b - a != delta for a, b in zip(offs_o, offs_n)):
        return "offset table is not the old one shifted by the header's growth"
    if old[eo + 8 * n :] != new[en + 8 * n :]:
        return "pixel blocks differ"
    return None


def compare_fhm(old, new):
    u32 = lambda b, o: struct.unpack_from("<I", b, o)[0]
    if u32(old, 8) != 1 or u32(new, 8) != 2:
        return "versions are not 1 -> 2"
    if old[12:36] != new[12:36] or old[40:48] != new[40:48]:
        return "fixed header fields differ"
    ho, hn = u32(old, 36), u32(new, 36)
    if hn != ho + 64:
        return f"header length {ho} -> {hn}"
    if old[64:-32] != new[128:-32]:
        return "group descriptors or payload differ"
    if all(x == 0 for x in new[48:128]):
        return "new file has no identity"
    return None


def strip_manifest(v, grown=0):
    """The manifest without run keys and versions; `grown`: what the .fhm header grew by, taken
    off the new manifest's `bytes_per_tile`."""
    if isinstance(v, dict):
        return {
            k: (x - grown if k == "bytes_per_tile" else strip_manifest(x, grown))
            for k, x in v.items()
            if k not in ("run_key", "format_version")
        }
    if isinstance(v, list):
        return [strip_manifest(x, grown) for x in v]
    if isinstance(v, str) and v.startswith("penumbra-") and v[-2:] in ("-1", "-2"):
        return v[:-2]
    return v


def main():
    old_root, new_root = sys.argv[1], sys.argv[2]
    counts, bad = {}, []
    for root, dirs, files in os.walk(old_root):
        dirs[:] = [d for d in dirs if d != ".penumbra"]
        for f in files:
            po = os.path.join(root, f)
            rel = os.path.relpath(po, old_root)
            pn = os.path.join(new_root, rel)
            if not os.path.exists(pn):
                bad.append(f"{rel}: missing in the new tree")
                continue
            old, new = open(po, "rb").read(), open(pn, "rb").read()
            if f.endswith(".exr"):
                kind, err = "exr", compare_exr(old, new)
            elif f.endswith(".fhm"):
                kind, err = "fhm", compare_fhm(old, new)
            elif f == "tileset.json":
                kind = "manifest"
                same = strip_manifest(json.loads(old)) == strip_manifest(json.loads(new), 64)
                err = None if same else "manifests differ beyond run keys, versions and the .fhm header's 64 bytes"
            else:
                kind, err = "other", None if old == new else "bytes differ"
            counts[kind] = counts.get(kind, 0) + 1
            if err:
                bad.append(f"{rel}: {err}")
    print("compared:", ", ".join(f"{v} {k}" for k, v in sorted(counts.items())))
    if bad:
        print("\n".join(bad))
        sys.exit(1)
    print("only identity-related bytes differ: every EXR's pixel blocks and every .fhm payload are byte-identical")


if __name__ == "__main__":
    main()
