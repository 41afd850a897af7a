"""The scene schema: one frozen dataclass per TOML section.

Units are in the key names. Every key's allowed range lives in its :func:`spec`; rules
that relate several keys live in :func:`tactip_sim.scene.load._cross_checks`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ._spec import nonneg, poisson, positive, spec

PAD_SHAPES = ("dome", "block")
LENS_MODELS = ("equidistant", "equisolid", "stereographic", "rectilinear", "kannala_brandt")
INDENTERS = ("plate", "sphere", "cylinder", "edge", "mesh")
PIN_MODELS = ("embedded", "rod", "beam")
PIN_LAYOUTS = ("lattice", "hex_rings", "circle_rings")
PIN_MAPPINGS = ("arc", "vertical")
FRAME_AVERAGES = ("features", "image")
REFRACTION = ("none", "analytic", "path")
MATERIAL_MODELS = ("linear", "neo_hookean")
CONTACT_SOLVERS = ("reduced", "full")
CONTACT_REFINEMENTS = ("off", "auto")
PIN_FRICTIONS = ("none", "stick")
SHADINGS = ("diffused", "lambert")
CAP_LAYERS = ("mitsuba", "raster")


@dataclass(frozen=True)
class Pad:
    """The finger-pad's outer shape (sensor frame: window outer face at z = 0, +x distal).

    ``dome``: an elliptical footprint with a vertical wall of ``wall_height_mm`` topped by a
    half-ellipsoidal dome reaching ``height_mm`` at the apex. ``block``: a box
    ``footprint_length_mm × footprint_width_mm × height_mm`` (the Hertz validation scene).
    """

    shape: str = spec("dome", "str", "outer shape of the pad", choices=PAD_SHAPES)
    footprint_length_mm: float = positive(38.5, "footprint extent along x (distal axis)", hi=500)
    footprint_width_mm: float = positive(28.0, "footprint extent along y", hi=500)
    height_mm: float = positive(7.5, "window outer face (z = 0) to skin apex", hi=500)
    wall_height_mm: float = nonneg(2.5, "dome only: vertical wall below the dome", hi=500)


@dataclass(frozen=True)
class Material:
    youngs_modulus_kpa: float = positive(900.0, "Young's modulus", hi=1e9)
    poisson_ratio: float = poisson(0.45)


@dataclass(frozen=True)
class Skin(Material):
    """The printed rubber skin (Tango Black+). Ignored by ``block`` pads."""

    thickness_mm: float = positive(1.0, "skin thickness (normal to the surface)", hi=50)


@dataclass(frozen=True)
class Gel(Material):
    """The clear silicone gel filling the cavity between skin and window."""

    youngs_modulus_kpa: float = positive(30.0, "Young's modulus", hi=1e9)
    poisson_ratio: float = poisson(0.45)
    refractive_index: float = spec(1.41, "float", "refractive index", lo=1.0, hi=3.0)


@dataclass(frozen=True)
class Pins:
    """Pins on the inside of the skin, with marker caps at the tips.

    ``layout`` (default ``lattice``, the seed sensor's) picks the pattern; ``hex_rings`` and
    ``circle_rings`` are the Bristol hemispherical TacTips' (127 = 6 rings, 331 = 10 rings).
    ``layout``, ``rotation_deg`` and ``mapping`` are left out of the scene's dict and hash at
    their defaults, so scenes written before they existed keep their hashes.

    The lattice pitch is measured along the skin's inner surface (an azimuthal-equidistant map
    from the apex), so pins keep their spacing over the curved dome; the lattice is clipped to a
    scaled copy of the footprint chosen so that exactly ``count`` pins fall inside.
    """

    count: int = spec(97, "int", "number of pins (0 = none)", lo=0, hi=2000)
    pitch_mm: float = positive(3.0, "lattice pitch along the skin", hi=100)
    length_mm: float = positive(3.0, "pin length, root on the skin to tip", hi=100)
    diameter_mm: float = positive(2.0, "pin diameter", hi=100)
    marker_diameter_mm: float = positive(1.6, "white marker cap diameter (assumed)", hi=100)
    clearance_mm: float = nonneg(0.5, "least gap between a pin tip and the window", hi=100)
    model: str = spec(
        "rod", "str", "how a tip follows the skin: embedded, a material point of the gel; rod, "
        "a rigid rod turning with the skin under its base; beam, an elastic rod bonded to the "
        "skin and held by the gel (linear material only)", choices=PIN_MODELS)
    layout: str = spec(
        "lattice", "str", "lattice: the triangular lattice clipped to the footprint; hex_rings: "
        "the lattice's hexagonal rings about the apex; circle_rings: concentric rings of 6k pins "
        "(ring k at arc length k * pitch); ring layouts need count = 1 + 3n(n + 1)",
        choices=PIN_LAYOUTS,
    )
    rotation_deg: float = spec(0.0, "float", "rotation of the layout about the apex (+z)",
                               lo=-180, hi=180)
    mapping: str = spec(
        "arc", "str", "how a ring layout's flat points reach the skin: arc, at their distance "
        "from the apex along the skin (an azimuthal-equidistant map); vertical, straight up "
        "onto the skin (a flat lattice projected along the tip's axis)", choices=PIN_MAPPINGS)


@dataclass(frozen=True)
class Window:
    """The clear acrylic window glued into the rim; its outer face is z = 0."""

    thickness_mm: float = positive(2.0, "acrylic thickness", hi=50)
    refractive_index: float = spec(1.49, "float", "refractive index", lo=1.0, hi=3.0)
    rim_width_mm: float = nonneg(2.0, "rim width around the footprint", hi=100)
    # docs/fem.md "Pins that stick to the window": the model bonds the gel to the window's
    # inner face, so a pin's end pressed through it onto the window cannot slide on a free
    # surface; no friction coefficient of a cap on acrylic through silicone was found
    pin_friction: str = spec(
        "none", "str", "a pin's end on the window's inner face slides freely (none) or sticks "
        "where it touched (stick; the neo-Hookean solver only)", choices=PIN_FRICTIONS,
    )


@dataclass(frozen=True)
class Body:
    """The rigid fingertip body below the window, and the protrusion by which the hand's distal
    unit holds the fingertip: it enters the body from the fingertip's base, i.e. the pad's
    proximal end (−x), which is why the camera is shifted forward (+x) and tilted back."""

    depth_mm: float = positive(20.0, "window inner face to the back of the body", hi=500)
    protrusion_length_mm: float = nonneg(15.0, "protrusion extent along x", hi=500)
    protrusion_height_mm: float = nonneg(14.0, "protrusion extent up from the body's back", hi=500)
    protrusion_end_x_mm: float = spec(
        -10.0, "float", "x at which the protrusion ends (it spans x below this)", lo=-500, hi=500
    )


@dataclass(frozen=True)
class Camera:
    """The camera below the window; the lens centre sits ``distance_mm`` below the window's
    inner face, ``shift_mm`` forward (+x), its optical axis tilted ``tilt_deg`` from +z towards
    −x (back over the pad, away from the protrusion) by a rotation about +y."""

    distance_mm: float = positive(14.0, "window inner face to the lens centre", hi=500)
    shift_mm: float = spec(3.0, "float", "forward shift of the lens along +x", lo=-500, hi=500)
    tilt_deg: float = spec(8.0, "float", "tilt of the optical axis", lo=-45, hi=45)
    resolution: tuple[int, ...] = spec(
        [640, 480], "int_list", "image width, height (px)", length=2, lo=16, hi=8192
    )
    pixel_pitch_um: float = positive(8.4, "pixel pitch (2.8 um x 3 binning, assumed)", hi=100)
    principal_offset_px: tuple[float, ...] = spec(
        [0.0, 0.0], "float_list", "principal point offset from the image centre", length=2,
        lo=-4096, hi=4096,
    )


@dataclass(frozen=True)
class Lens:
    model: str = spec("equidistant", "str", "projection model", choices=LENS_MODELS)
    focal_length_mm: float = spec(2.1, "float", "focal length", lo=0.2, hi=50)
    fov_deg: float = spec(150.0, "float", "full field of view", lo=10, hi=220)
    kb_coeffs: tuple[float, ...] = spec(
        [0.0, 0.0, 0.0, 0.0], "float_list", "Kannala-Brandt k1..k4", length=4, lo=-10, hi=10
    )


@dataclass(frozen=True)
class Lighting:
    """Four LEDs on two strips inside the body, close to the pad interface (assumed layout)."""

    strip_y_mm: float = nonneg(11.0, "|y| of the two LED strips", hi=500)
    led_x_mm: tuple[float, ...] = spec(
        [-7.0, 7.0], "float_list", "x of the LEDs along each strip", min_length=1, lo=-500,
        hi=500,
    )
    led_z_mm: float = spec(-3.0, "float", "height of the LEDs (below the window)", lo=-500, hi=0)
    led_intensity: float = positive(30.0, "radiant intensity per LED (arbitrary units)", hi=1e9)
    ambient: float = nonneg(0.0, "uniform ambient light", hi=1e6)


@dataclass(frozen=True)
class Imaging:
    """Rendering and the camera's noise model. All noise is seeded by the caller's ``rng``."""

    spp: int = spec(4, "int", "samples per pixel", lo=1, hi=4096)
    refraction: str = spec("analytic", "str", "window/gel refraction", choices=REFRACTION)
    shading: str = spec(
        "diffused", "str", "marker caps: uniform translucent (diffused, a cap layer over a "
        "static background) or lit point by point (lambert, whole scene each frame)",
        choices=SHADINGS,
    )
    exposure: float = positive(1.0, "exposure gain", hi=1e6)
    read_noise: float = nonneg(2.0, "read noise standard deviation (DN)", hi=255)
    shot_noise: float = nonneg(0.5, "shot-noise gain (DN per sqrt DN)", hi=100)
    blur_px: float = nonneg(0.6, "Gaussian blur sigma (px)", hi=100)
    vignetting: float = spec(0.3, "float", "relative fall-off at the image corner", lo=0, hi=1)
    colour: bool = spec(False, "bool", "render RGB (true) or grey (false)")
    cap_layer: str = spec(
        "raster", "str", "per-pose marker caps: drawn by the compiled rasteriser over the "
        "cached Mitsuba background (raster, the default: diffused caps, analytic or no "
        "refraction) or rendered by Mitsuba every pose (mitsuba; the paper preset; "
        "docs/speed.md)", choices=CAP_LAYERS,
    )


@dataclass(frozen=True)
class Indenter:
    """The rigid object the pad is pressed against (the protocol uses a flat plate)."""

    kind: str = spec("plate", "str", "indenter shape", choices=INDENTERS)
    radius_mm: float = positive(10.0, "sphere/cylinder/edge-rounding radius", hi=1e4)
    length_mm: float = positive(60.0, "cylinder/edge length", hi=1e4)
    mesh: str = spec("", "str", "path of a watertight mesh (kind = 'mesh'), relative to the scene")
    friction_coefficient: float = nonneg(
        0.0, "Coulomb friction between indenter and skin (0 = frictionless; docs/fem.md, "
        "Friction)", hi=10)


@dataclass(frozen=True)
class Fidelity:
    # hi: beyond ~16 mm the mesh no longer coarsens (the surface sets it: 3240, 3139, 3179
    # tets at 8, 16, 30 mm) while pytetwild slows (11, 20, 76 s; > 300 s at 100 mm):
    # measured in docs/robustness.md
    mesh_edge_mm: float = spec(2.0, "float", "target tet edge length", lo=0.2, hi=16)
    tetwild_epsilon: float = spec(3e-3, "float", "pytetwild envelope (relative)", lo=1e-5, hi=0.1)
    surface_resolution: int = spec(48, "int", "surface triangulation rings/segments", lo=8, hi=512)
    refine_edge_mm: float = nonneg(
        0.0, "edge length near the top centre (0 = uniform mesh)", hi=100
    )
    refine_radius_mm: float = nonneg(3.0, "radius of the refined zone around the top centre",
                                     hi=500)
    element_order: int = spec(2, "int", "1 = linear P1 tets, 2 = quadratic P2 tets", lo=1, hi=2)
    material_model: str = spec("linear", "str", "constitutive law", choices=MATERIAL_MODELS)
    contact_solver: str = spec("reduced", "str", "contact solve", choices=CONTACT_SOLVERS)
    # docs/fem.md "Discretisation error and contact refinement"
    contact_tolerance: float = spec(
        0.03, "float", "relative force error a solve may have before it warns (and, with "
        "contact_refinement = 'auto', before the contact is meshed finer)", lo=0, hi=1,
        lo_open=True,
    )
    contact_refinement: str = spec(
        "off", "str", "mesh the contact zone finer when the estimated error would exceed "
        "contact_tolerance (auto) or never (off)", choices=CONTACT_REFINEMENTS,
    )
    # docs/convergence.md "An estimate per marker": 0.01 mm, the convergence criterion of the
    # mesh study (issue 16), not a measured quantity
    marker_tolerance_mm: float = spec(
        0.01, "float", "estimated marker (pin tip) error a full-field solve may have before it "
        "warns (and, with pin_refinement = 'auto', before the skin around those pins is meshed "
        "finer), mm", lo=0, hi=10, lo_open=True,
    )
    pin_refinement: str = spec(
        "off", "str", "mesh the skin around the pins whose estimated marker error exceeds "
        "marker_tolerance_mm finer and solve again (auto; full-field solvers) or never (off)",
        choices=CONTACT_REFINEMENTS,
    )


@dataclass(frozen=True)
class Protocol:
    """The roll/pitch calibration protocol of the reference paper."""

    training_depth_mm: float = nonneg(1.0, "indentation of the training sweep (assumed)", hi=50)
    roll_range_deg: tuple[float, ...] = spec(
        [-16.0, 16.0], "float_list", "roll min, max", length=2, lo=-90, hi=90
    )
    roll_step_deg: float = positive(2.0, "roll grid step", hi=180)
    pitch_range_deg: tuple[float, ...] = spec(
        [-11.0, 3.0], "float_list", "pitch min, max", length=2, lo=-90, hi=90
    )
    pitch_step_deg: float = positive(1.0, "pitch grid step", hi=180)
    test_depth_offsets_mm: tuple[float, ...] = spec(
        [-0.5, 0.0, 0.5], "float_list", "test-set depths relative to training", min_length=1,
        lo=-50, hi=50,
    )
    test_poses: int = spec(200, "int", "random poses per test set", lo=1, hi=1_000_000)
    frames_per_sample: int = spec(60, "int", "frames averaged per sample (paper: ~60)", lo=1,
                                  hi=10_000)
    tips: tuple[str, ...] = spec(["A", "B", "C"], "str_list", "tip instances", min_length=1)
    seed: int = spec(0, "int", "seed of the test poses and the tip perturbations", lo=0)
    frame_average: str = spec(
        "image", "str", "how a sample's frames are averaged: image, the frames averaged pixel "
        "by pixel and the mean image perceived once (the default, 2.6x faster, growth-CoP R² "
        "within 0.005: docs/speed.md); features, each frame perceived and the features "
        "averaged (the paper's; the paper preset)",
        choices=FRAME_AVERAGES)


@dataclass(frozen=True)
class Tolerances:
    """Standard deviations of what varies between printed tips (all assumed)."""

    pin_position_mm: float = nonneg(0.05, "pin position in the lattice plane", hi=10)
    skin_thickness_mm: float = nonneg(0.05, "skin thickness", hi=10)
    camera_shift_mm: float = nonneg(0.2, "camera mount shift", hi=10)
    camera_tilt_deg: float = nonneg(0.5, "camera mount tilt", hi=45)
    stiffness_rel: float = nonneg(0.05, "relative Young's modulus of skin and gel", hi=0.9)


@dataclass(frozen=True)
class Scene:
    """A whole, validated scene. Build with :func:`tactip_sim.load_scene`."""

    name: str = "scene"
    pad: Pad = field(default_factory=Pad)
    skin: Skin = field(default_factory=Skin)
    gel: Gel = field(default_factory=Gel)
    pins: Pins = field(default_factory=Pins)
    window: Window = field(default_factory=Window)
    body: Body = field(default_factory=Body)
    camera: Camera = field(default_factory=Camera)
    lens: Lens = field(default_factory=Lens)
    lighting: Lighting = field(default_factory=Lighting)
    imaging: Imaging = field(default_factory=Imaging)
    indenter: Indenter = field(default_factory=Indenter)
    fidelity: Fidelity = field(default_factory=Fidelity)
    protocol: Protocol = field(default_factory=Protocol)
    tolerances: Tolerances = field(default_factory=Tolerances)
    presets: dict = field(default_factory=dict)
    """Named fidelity presets, ``{name: {section: {key: value}}}``: the built-in ones
    (:data:`tactip_sim.scene.presets.BUILTIN_PRESETS`) updated by the file's ``[presets.NAME]``
    tables. Not part of the scene hash: they are alternatives, not applied settings."""
    source: str = ""  # file the scene came from ("" if built in code); not part of the hash

    @property
    def is_block(self) -> bool:
        return self.pad.shape == "block"


SECTIONS: dict[str, type] = {
    "pad": Pad,
    "skin": Skin,
    "gel": Gel,
    "pins": Pins,
    "window": Window,
    "body": Body,
    "camera": Camera,
    "lens": Lens,
    "lighting": Lighting,
    "imaging": Imaging,
    "indenter": Indenter,
    "fidelity": Fidelity,
    "protocol": Protocol,
    "tolerances": Tolerances,
}
