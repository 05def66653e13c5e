"""LZF decompression, for PCD files saved `DATA binary_compressed` (PCL compresses them with liblzf).

The format is liblzf's (Marc Lehmann, BSD-2-Clause; lzf_d.c), reimplemented here from its description: a
control byte c < 32 starts a run of c + 1 literal bytes; otherwise c >> 5 is a length (7: add the next
byte), and the next byte with the low 5 bits of c gives how far back to copy length + 2 bytes from
(copies may overlap the bytes they produce, which is how runs are encoded).
"""

from __future__ import annotations

import numba
import numpy as np

from msa_slam.errors import InputError


@numba.njit(cache=True)
def _decompress(data: np.ndarray, out: np.ndarray) -> int:
    """Decode `data` into `out`; the number of bytes written, or -1 - position of the first bad byte."""
    i, o, n, size = 0, 0, len(data), len(out)
    while i < n:
        ctrl = data[i]
        i += 1
        if ctrl < 32:
            length = ctrl + 1
            if i + length > n or o + length > size:
                return -1 - i
            out[o : o + length] = data[i : i + length]
            i += length
            o += length
            continue
        length = ctrl >> 5
        if length == 7:
            if i >= n:
                return -1 - i
            length += data[i]
            i += 1
        if i >= n:
            return -1 - i
        ref = o - ((ctrl & 0x1F) << 8) - data[i] - 1
        i += 1
        length += 2
        if ref < 0 or o + length > size:
            return -1 - i
        for k in range(length):
            out[o + k] = out[ref + k]
        o += length
    return o


def lzf_decompress(data: bytes, size: int, where: str = "LZF data") -> bytes:
    """The `size` bytes that LZF-compressed `data` decode to; InputError naming `where` if they do not."""
    out = np.empty(size, dtype=np.uint8)
    written = _decompress(np.frombuffer(data, dtype=np.uint8), out)
    if written < 0:
        raise InputError(f"{where}: corrupt LZF stream at compressed byte {-1 - written} of {len(data)}")
    if written != size:
        raise InputError(f"{where}: LZF stream decodes to {written} bytes, the header declares {size}")
    return out.tobytes()
