"""BimArt's two-part articulated objects: primitives with exact signed distances, categories, pure JAX poses."""

from handx_jax.objects.articulated import (  # noqa: F401
    BOTTOM, NO_PART, PART_NAMES, STATE_DIM, TOP, ArticulatedObject, anonymous, canonical_part_sdf, directions_to_world,
    object_sdf, object_sdf_frames, part_areas, part_pose, part_sdf, surface_samples, to_part, to_world,
    world_surface)
from handx_jax.objects.categories import CATEGORIES, Category, sample_instance  # noqa: F401
