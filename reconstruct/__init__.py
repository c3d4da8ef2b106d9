"""WonderHuman reconstruction library: body model, data, avatar, rasterizer, losses, training."""

import os as _os

# Idle OpenMP workers sleep instead of spinning: with torch's pool and the rasterizer's
# parallel loops sharing 2 cores with other work, spinning workers cost up to 10x per step.
# (Only effective when set before torch initialises OpenMP; the CLI imports this package first.)
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
