"""A PNG reader for the tests, standard library only (no Pillow on the test machine's list):
non-interlaced greyscale, RGB, grey+alpha or RGBA at 8 or 16 bits, as terrad's exports
(16-bit greyscale) and Chromium's screenshots (8-bit RGB or RGBA) write them."""
import struct
import zlib

CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}  # PNG colour type -> samples per pixel


def read_png(path):
    """(width, height, depth, channels, samples): samples is one flat list, row-major,
    `channels` values per pixel, each 0..2**depth-1."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG")
    at, idat, width, height, depth, channels = 8, b"", 0, 0, 0, 0
    while at < len(data):
        n, kind = struct.unpack(">I4s", data[at:at + 8])
        body = data[at + 8:at + 8 + n]
        if kind == b"IHDR":
            width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", body)
            if depth not in (8, 16) or colour not in CHANNELS or interlace != 0:
                raise ValueError(f"{path}: depth {depth}, colour type {colour}, interlace {interlace} unsupported")
            channels = CHANNELS[colour]
        elif kind == b"IDAT":
            idat += body
        at += 12 + n
    bpp = channels * depth // 8
    raw, stride = zlib.decompress(idat), width * bpp
    rows, prev = [], bytearray(stride)
    for y in range(height):
        ft, line = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):  # undo the row's filter (PNG spec, section 9)
            a = line[i - bpp] if i >= bpp else 0
            b, c = prev[i], prev[i - bpp] if i >= bpp else 0
            if ft == 1:
                line[i] = (line[i] + a) & 255
            elif ft == 2:
                line[i] = (line[i] + b) & 255
            elif ft == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif ft == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        rows.append(bytes(line))
        prev = line
    joined = b"".join(rows)
    samples = list(joined) if depth == 8 else list(struct.unpack(f">{len(joined) // 2}H", joined))
    return width, height, depth, channels, samples
