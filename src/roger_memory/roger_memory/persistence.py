"""Long-term memory file: exemplars, addresses and network weights, written atomically.

Layout (little endian)::

    b"ROGERMEM" | u32 format version | u64 header length | header (UTF-8 JSON) | payload

The header holds the feature layout, the configuration, the seed, the number of addresses,
and the length and SHA-256 of the payload; the payload is an ``.npz`` archive (no pickle)
of the exemplars, their known masks and addresses, and every network tensor. A file cut off
anywhere, or altered, fails the length or checksum test and is refused with a
:class:`~roger_common.errors.MemoryFileError` that names the file. Files are written with
:func:`roger_common.atomic.atomic_write_bytes` (temporary file, fsync, rename), so a crash
at any moment leaves the old file or the new one, never a broken one.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import struct
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from roger_common.atomic import atomic_write_bytes
from roger_common.errors import MemoryFileError
from roger_common.types import FeatureMode, feature_names

#: First bytes of every long-term-memory file.
MAGIC: bytes = b"ROGERMEM"
#: Bumped whenever the layout changes; older or newer files are refused.
FORMAT_VERSION: int = 2
_PREFIX = struct.Struct("<8sIQ")
_MAX_HEADER_BYTES = 1 << 20
_WEIGHT_PREFIX = "net."


@dataclass
class MemorySnapshot:
    """Everything the long-term memory needs to come back exactly as it was.

    Attributes:
        config: MemoryConfig.to_dict() of the memory that was saved.
        seed: Seed of the memory (retraining after a load stays reproducible).
        n_addresses: Number of long-term-memory addresses (network output units).
        exemplars: (n, F) float32 stored feature vectors (F: the length of the feature
            mode ``config["features"]``; a file without that key is of the paper's mode).
        known: (n, F) bool known masks of the exemplars.
        addresses: (n,) int64 address of each exemplar.
        weights: Network state_dict as numpy arrays, by parameter name.
        stored: (n,) bool: the look came with the store of its address (False: added by
            a later identification). None: all stored.
    """

    config: dict[str, Any]
    seed: int
    n_addresses: int
    exemplars: np.ndarray
    known: np.ndarray
    addresses: np.ndarray
    weights: dict[str, np.ndarray] = field(default_factory=dict)
    stored: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.stored is None:
            self.stored = np.ones(len(self.addresses), bool)


def snapshot_mode(config: dict[str, Any]) -> FeatureMode:
    """The feature mode of a saved memory's configuration (files from before the modes
    carry no ``features`` key: the paper's eleven)."""
    try:
        return FeatureMode.parse(config.get("features", FeatureMode.PAPER.value))
    except ValueError as exc:
        raise MemoryFileError(f"memory configuration: {exc}") from None


def encode_snapshot(snapshot: MemorySnapshot) -> bytes:
    """Serialise a snapshot to the bytes of a memory file."""
    buf = io.BytesIO()
    arrays = {
        "exemplars": np.asarray(snapshot.exemplars, np.float32),
        "known": np.asarray(snapshot.known, bool),
        "addresses": np.asarray(snapshot.addresses, np.int64),
        "stored": np.asarray(snapshot.stored, bool),
    }
    arrays.update({_WEIGHT_PREFIX + k: np.asarray(v) for k, v in snapshot.weights.items()})
    np.savez(buf, **arrays)  # type: ignore[arg-type]
    payload = buf.getvalue()
    header = json.dumps({
        "format": "roger_memory",
        "feature_names": list(feature_names(snapshot_mode(snapshot.config))),
        "config": snapshot.config,
        "seed": int(snapshot.seed),
        "n_addresses": int(snapshot.n_addresses),
        "payload_bytes": len(payload),
        "payload_sha256": hashlib.sha256(payload).hexdigest(),
    }, sort_keys=True).encode("utf-8")
    return _PREFIX.pack(MAGIC, FORMAT_VERSION, len(header)) + header + payload


def decode_snapshot(data: bytes, source: str = "<bytes>") -> MemorySnapshot:
    """Parse the bytes of a memory file.

    Args:
        data: The whole file content.
        source: Name used in error messages (the file path).

    Raises:
        MemoryFileError: The data is not a memory file, is cut off, corrupt, or was written
            for another feature layout or format version.
    """
    if len(data) < _PREFIX.size:
        _fail(source, f"cut off: {len(data)} bytes, shorter than the {_PREFIX.size}-byte prefix")
    magic, version, header_len = _PREFIX.unpack_from(data)
    if magic != MAGIC:
        _fail(source, f"not a Roger long-term-memory file (starts with {magic!r})")
    if version != FORMAT_VERSION:
        _fail(source, f"format version {version}, this code reads version {FORMAT_VERSION}")
    if header_len > _MAX_HEADER_BYTES:
        _fail(source, f"corrupt: header length {header_len} is implausible")
    start = _PREFIX.size + header_len
    if len(data) < start:
        _fail(source, f"cut off inside the header ({len(data)} of at least {start} bytes)")
    try:
        header = json.loads(data[_PREFIX.size:start].decode("utf-8"))
        expected_len = int(header["payload_bytes"])
        digest = str(header["payload_sha256"])
        names = list(header["feature_names"])
        config = dict(header["config"])
        seed = int(header["seed"])
        n_addresses = int(header["n_addresses"])
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
        _fail(source, f"corrupt header ({exc})")
    payload = data[start:]
    if len(payload) != expected_len:
        _fail(source, f"cut off or padded: payload has {len(payload)} bytes, "
              f"the header says {expected_len}")
    if hashlib.sha256(payload).hexdigest() != digest:
        _fail(source, "corrupt: payload checksum does not match")
    modes = [m for m in FeatureMode if names == list(feature_names(m))]
    if not modes:
        _fail(source, f"incompatible feature layout {names}, expected one of "
              + "; ".join(f"{m.value}: {list(feature_names(m))}" for m in FeatureMode))
    if snapshot_mode(config) is not modes[0]:
        _fail(source, f"its features {names} are not those of its configuration's mode "
              f"{config.get('features')!r}")
    config["features"] = modes[0].value
    dim = len(names)
    try:
        with np.load(io.BytesIO(payload), allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
        exemplars = arrays.pop("exemplars").astype(np.float32)
        known = arrays.pop("known").astype(bool)
        addresses = arrays.pop("addresses").astype(np.int64)
        stored = arrays.pop("stored").astype(bool)
    except (ValueError, KeyError, OSError, zipfile.BadZipFile) as exc:
        _fail(source, f"corrupt payload ({exc})")
    n = len(addresses)
    if (exemplars.shape != (n, dim) or known.shape != (n, dim)
            or stored.shape != (n,)):
        _fail(source, f"incompatible exemplar shapes {exemplars.shape} / {known.shape}")
    if n and (addresses.min() < 0 or addresses.max() >= n_addresses):
        _fail(source, f"corrupt: exemplar addresses outside [0, {n_addresses})")
    if n_addresses and len(np.unique(addresses)) != n_addresses:
        _fail(source, "corrupt: some address has no exemplar")
    weights = {k[len(_WEIGHT_PREFIX):]: v for k, v in arrays.items()
               if k.startswith(_WEIGHT_PREFIX)}
    return MemorySnapshot(config, seed, n_addresses, exemplars, known, addresses, weights,
                          stored)


def save_snapshot(snapshot: MemorySnapshot, path: str | os.PathLike[str],
                  durable: bool = True) -> None:
    """Write a snapshot to ``path`` atomically (write a temporary file, then rename).

    ``durable``: fsync too (see :func:`roger_common.atomic.atomic_write_bytes`).
    """
    atomic_write_bytes(path, encode_snapshot(snapshot), durable=durable)


def load_snapshot(path: str | os.PathLike[str]) -> MemorySnapshot:
    """Read a snapshot from ``path``.

    Raises:
        MemoryFileError: The file is missing, unreadable, cut off, corrupt or incompatible;
            the message names the file.
    """
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise MemoryFileError(f"{path}: cannot read long-term memory ({exc.strerror})") from exc
    return decode_snapshot(data, str(path))


def _fail(source: str, problem: str) -> NoReturn:
    raise MemoryFileError(f"{source}: {problem}; delete or restore the long-term-memory file")
