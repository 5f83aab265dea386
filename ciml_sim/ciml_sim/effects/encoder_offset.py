"""Encoder offset in the simulator: the joint loop and the log read q + offset (no force)."""
from __future__ import annotations

from .base import SimEffect


class EncoderOffset(SimEffect):
    name = "encoder_offset"

    def configure(self, plant, effect, j):
        plant.encoder_offset[j] += effect.params["value"]


EFFECT = EncoderOffset()
