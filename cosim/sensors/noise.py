"""Image noise shared by the cameras: a per-frame exposure gain and per-pixel Gaussian noise,
all from the camera's seeded ``numpy.random.Generator`` (deterministic per seed and frame).

Per frame: gain ``brightness * (1 + lighting_noise * N(0, 1))`` on all channels (``brightness``:
a constant scene lighting, 1 by default) and an offset ``offset_noise * N(0, 1)`` (0-255 units;
the front camera's exposure noise is this gain and offset), then per-pixel Gaussian noise of
``noise_std`` (0-255 units), rounded and clipped to uint8. Draws per frame, in this order: the
gain (if lighting_noise > 0), the offset (if offset_noise > 0), the noise window (if
noise_std > 0). For speed the pixel noise
of a frame is a window, at a random offset, of a seeded bank of 2**21 Gaussian samples drawn
once (drawing 57 600 normals per frame costs ~0.9 ms); windows of two frames may overlap
(their noise is then the same sequence shifted by a random number of samples).
"""

from __future__ import annotations

import cv2
import numpy as np

NOISE_BANK = 1 << 21      # samples in the per-camera Gaussian noise bank (8 MiB float32)
_BYTES = np.arange(256, dtype=np.uint8)      # the values of a uint8 pixel
_VALUES = _BYTES.astype(np.float32)


class FrameNoise:
    """Adds exposure and pixel noise to H x W x C uint8 frames of one size."""

    def __init__(self, rng: np.random.Generator, noise_std: float, lighting_noise: float,
                 n_values: int, brightness: float = 1.0, offset_noise: float = 0.0) -> None:
        self.rng = rng
        self.noise_std = float(noise_std)
        self.lighting_noise = float(lighting_noise)
        self.brightness = float(brightness)
        self.offset_noise = float(offset_noise)
        self.bank: np.ndarray | None = None
        if self.noise_std > 0.0:
            # noise_std * N(0, 1) + 0.5 (the 0.5 makes the uint8 conversion round half up)
            bank = rng.standard_normal(NOISE_BANK + n_values, dtype=np.float32)
            bank *= self.noise_std
            bank += 0.5
            self.bank = bank

    @property
    def active(self) -> bool:
        return (self.noise_std > 0.0 or self.lighting_noise > 0.0 or self.brightness != 1.0
                or self.offset_noise > 0.0)

    def draw(self) -> tuple[float, float, int]:
        """A frame's draws (gain, offset, noise window start), in the order above: what
        ``apply`` takes from the generator; a frame nobody looks at takes them too
        (``FrontCamera.skip``), so the frames after it are the same."""
        if not self.active:
            return 1.0, 0.0, 0
        ln = self.lighting_noise
        gain = 1.0 + ln * self.rng.standard_normal() if ln else 1.0
        if self.brightness != 1.0:
            gain *= self.brightness
        offset = self.offset_noise * self.rng.standard_normal() if self.offset_noise else 0.0
        k = int(self.rng.integers(0, NOISE_BANK)) if self.bank is not None else 0
        return gain, offset, k

    def apply(self, img: np.ndarray, drawn: tuple[float, float, int] | None = None
              ) -> np.ndarray:
        """The frame with its noise: new draws, or ``drawn`` (a frame's, from ``draw``)."""
        if not self.active:
            return img
        if img.dtype != np.uint8:
            raise TypeError(f"FrameNoise: a uint8 frame, not {img.dtype}")
        gain, offset, k = self.draw() if drawn is None else drawn
        if self.bank is not None:
            noise = self.bank[k:k + img.size].reshape(img.shape)
            if offset:
                noise = noise + np.float32(offset)
            buf = cv2.scaleAdd(img.astype(np.float32), max(gain, 0.0), noise)
            np.clip(buf, 0.0, 255.0, out=buf)
            return buf.astype(np.uint8)
        # no pixel noise: the result is a function of the pixel's value alone, so it is
        # computed for the 256 values and looked up (the same bytes as computing it per pixel;
        # 0.1 ms against 1.3 ms at 856 x 480)
        if offset:      # convertScaleAbs would fold a negative value back up: clip instead
            lut = _VALUES * np.float32(max(gain, 0.0)) + np.float32(offset + 0.5)
            np.clip(lut, 0.0, 255.0, out=lut)
            lut = lut.astype(np.uint8)
        else:
            lut = cv2.convertScaleAbs(_BYTES, alpha=max(gain, 0.0))
        return lut[img] if img.size == 0 else cv2.LUT(img, lut).reshape(img.shape)
