"""Surface materials of simulated scenes and their procedural texture.

A material is what the renderer needs to shade a surface: diffuse reflectance per colour channel
(the red channel matters most: the lasers are 650 nm pointers), a specular part, and a procedural
texture. Texture matters for two reasons: real walls are never flat grey (the thesis' first
experiment used textured cardboard on purpose), and spot detection must not mistake texture for
laser spots.

The texture of a face is a sum of random 2D sinusoids in the face's own plane coordinates
(``surface_uv``, metres). Orientations and phases come from a generator seeded by the face's stable
key, so a face looks the same in every frame, also while it moves; wavelengths scale with the
material's ``texture_scale_m`` and the RMS contrast equals ``texture``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from edge.schema import require

# Waves of the procedural texture: (count, shortest and longest wavelength as multiples of
# texture_scale_m, amplitude before normalisation). Six waves at the feature size give the look,
# three finer ones keep it from looking like a plaid of pure stripes.
_TEXTURE_BANDS = ((6, 0.7, 1.5, 1.0), (3, 0.15, 0.35, 0.5))
TEXTURE_WAVES = sum(band[0] for band in _TEXTURE_BANDS)
TEXTURE_FLOOR = 0.05  # texture never makes a surface black: shading stays defined for the lasers
_TEXTURE_SALT = 0x5EED7E  # separates texture streams from any other use of the face key as a seed


@dataclass(frozen=True)
class Material:
    """How a surface reflects light. Values are 0..1 unless said."""

    name: str
    albedo: tuple[float, float, float]  # diffuse reflectance in R, G, B
    texture: float = 0.2  # RMS contrast of the procedural texture (0 = flat)
    texture_scale_m: float = 0.05  # typical feature size of the texture
    gloss: float = 0.0  # fraction of light reflected specularly (0 = matte)
    shininess: float = 30.0  # Phong exponent of the specular lobe

    def __post_init__(self) -> None:
        require(bool(self.name.strip()), "name", "must not be empty")
        for i, a in enumerate(self.albedo):
            require(0.0 <= a <= 1.0, f"albedo[{i}]", f"must be within 0..1, got {a}")
        require(0.0 <= self.texture <= 1.0, "texture", f"must be within 0..1, got {self.texture}")
        require(
            self.texture_scale_m > 0,
            "texture_scale_m",
            f"must be positive, got {self.texture_scale_m}",
        )
        require(0.0 <= self.gloss <= 1.0, "gloss", f"must be within 0..1, got {self.gloss}")
        require(self.shininess > 0, "shininess", f"must be positive, got {self.shininess}")


# The built-in materials; scene files may add their own under [materials.<name>].
BUILTIN_MATERIALS: MappingProxyType[str, Material] = MappingProxyType(
    {
        m.name: m
        for m in (
            # Painted plaster: bright and almost featureless, the common indoor wall. Easy for the
            # lasers, the worst case for anything that needs texture.
            Material("paint-white", (0.80, 0.80, 0.78), texture=0.05, texture_scale_m=0.02),
            # The thesis' first experiment: a small room of textured cardboard walls.
            Material("cardboard", (0.55, 0.45, 0.35), texture=0.25, texture_scale_m=0.05),
            # Desks, tables, shelves, doors: mid-dark with a grain and a faint sheen.
            Material("wood", (0.45, 0.30, 0.18), texture=0.20, texture_scale_m=0.03, gloss=0.05),
            # Office floors: grey, fine-grained, matte.
            Material("carpet-grey", (0.30, 0.30, 0.30), texture=0.15, texture_scale_m=0.01),
            # Kitchen and bathroom walls/floors: a specular highlight can look like a laser spot.
            Material(
                "tile-glossy", (0.70, 0.70, 0.68), texture=0.10, texture_scale_m=0.15,
                gloss=0.3, shininess=60.0,
            ),
            # Filing cabinets, appliances: little diffuse light comes back, much goes specular.
            Material(
                "metal-glossy", (0.55, 0.56, 0.58), texture=0.03, texture_scale_m=0.05,
                gloss=0.5, shininess=90.0,
            ),
            # Sofas, curtains, dark clothes: returns under a tenth of the light, a hard case for
            # spot detection at long range.
            Material("fabric-dark", (0.09, 0.08, 0.08), texture=0.15, texture_scale_m=0.01),
            # Movers: average clothing.
            Material("person", (0.30, 0.27, 0.25), texture=0.15, texture_scale_m=0.10),
            # The void behind doorways: far away and dim, so that spots there are lost as they
            # would be in a dark corridor.
            Material("beyond", (0.20, 0.20, 0.20), texture=0.0),
            # Laminated kitchen fronts: light, smooth, moderately glossy.
            Material(
                "kitchen-cabinet", (0.75, 0.72, 0.65), texture=0.03, texture_scale_m=0.05,
                gloss=0.25, shininess=50.0,
            ),
            # Enamelled appliances (fridge, dishwasher): white and glossy.
            Material(
                "appliance-white", (0.85, 0.85, 0.85), texture=0.02, texture_scale_m=0.05,
                gloss=0.35, shininess=80.0,
            ),
            # Whiteboards: the brightest surface in an office, with a sharp highlight.
            Material(
                "whiteboard", (0.88, 0.88, 0.88), texture=0.02, texture_scale_m=0.05,
                gloss=0.4, shininess=120.0,
            ),
            # Dark stone or composite worktops: glossy and dark, another hard case.
            Material(
                "worktop-dark", (0.22, 0.20, 0.18), texture=0.10, texture_scale_m=0.02,
                gloss=0.25, shininess=70.0,
            ),
        )
    }
)


def texture_waves(material: Material, key: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The texture of a face with this material and stable `key`.

    Returns wave vectors (W, 2) in rad/m, phases (W,) and amplitudes (W,), such that the texture is
    ``max(TEXTURE_FLOOR, 1 + sum(amp * cos(k · uv + phase)))``. The sum has mean 0 and RMS
    ``material.texture``, so the texture's mean is 1 (slightly more where the floor clips).
    """
    k = np.zeros((TEXTURE_WAVES, 2))
    phase = np.zeros(TEXTURE_WAVES)
    amp = np.zeros(TEXTURE_WAVES)
    if material.texture == 0.0:
        return k, phase, amp
    rng = np.random.default_rng((int(key) & 0x7FFF_FFFF_FFFF_FFFF, _TEXTURE_SALT))
    i = 0
    for count, shortest, longest, a in _TEXTURE_BANDS:
        wavelength = material.texture_scale_m * rng.uniform(shortest, longest, count)
        angle = rng.uniform(0.0, math.pi, count)
        k[i : i + count, 0] = 2.0 * math.pi / wavelength * np.cos(angle)
        k[i : i + count, 1] = 2.0 * math.pi / wavelength * np.sin(angle)
        phase[i : i + count] = rng.uniform(0.0, 2.0 * math.pi, count)
        amp[i : i + count] = a
        i += count
    # A sum of cosines with random phases has variance sum(a²)/2.
    amp *= material.texture / math.sqrt(float(np.sum(amp * amp)) / 2.0)
    return k, phase, amp
