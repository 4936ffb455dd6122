"""Task families, one module each; importing this package registers every env."""

from mikasa_envs.tasks import (  # noqa: F401
    find_imposter_color,
    find_imposter_shape,
    find_imposter_shape_and_color,
    remember_color,
    remember_shape,
    remember_shape_and_color,
)
