"""The limits and defaults the package shares with the Rust crates: each name here is a Rust
constant of the same name and value (core/src/io/limits.rs, bundle/src/graph.rs and scene.rs,
core/src/render, runtime/src/scene.rs and network.rs). runtime/tests/cli.rs
(python_limits_match_the_core) checks both ways: every value here equals its Rust constant,
and every Rust constant the package needs is here. Change a value in Rust, then here."""

#: Largest image side in pixels.
MAX_IMAGE_SIDE = 16_384
#: Most pixels in one frame (4096²).
MAX_FRAME_PIXELS = 16_777_216
#: Most poses per list in scene.json, and frames per command.
MAX_FRAMES = 10_000
#: Most samples per ray (n_coarse + n_fine, or march_steps).
MAX_SAMPLES_PER_RAY = 4_096
#: Most rays per network call (``chunk``).
MAX_CHUNK = 1_048_576
#: Most points per network call: rays per call × samples per ray.
MAX_POINTS_PER_CALL = 4_194_304
#: Most cells per axis of an occupancy grid.
MAX_GRID_RESOLUTION = 512
#: Most onnxruntime sessions per graph (``threads``).
MAX_THREADS = 1_024
#: Largest scene.json.
MAX_JSON_BYTES = 67_108_864
#: Largest graph file (protobuf messages stop at 2 GiB).
MAX_GRAPH_BYTES = 2_147_483_648
#: Rays per network call unless told otherwise (fewer when a ray has many samples).
DEFAULT_CHUNK = 4_096
#: Marching intervals per ray when scene.json does not say.
DEFAULT_MARCH_STEPS = 256
#: Most points per onnxruntime run of one session.
POINTS_PER_RUN = 2_048
#: The scene.json formats read.
READ_FORMATS = ("nerf-rs-scene-1", "nerf-rs-scene-2", "nerf-rs-scene-3")
