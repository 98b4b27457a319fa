"""Layout generators: procedural families and voxel shapes merged into bricks."""
from .procedural import (
    FAMILIES,
    LOAD_BLOCK_KG,
    bridge,
    cuboid,
    lever,
    pallet_of_boxes,
    random_family_layout,
    stairs,
    tower,
    voxel_layout,
    wall,
    with_floating,
)
from .voxels import (
    DEFAULT_BRICKS,
    SHAPE_KINDS,
    ground,
    merge_voxels,
    random_blob,
    random_voxel_shape,
)

__all__ = [
    "DEFAULT_BRICKS",
    "FAMILIES",
    "LOAD_BLOCK_KG",
    "SHAPE_KINDS",
    "bridge",
    "cuboid",
    "ground",
    "lever",
    "merge_voxels",
    "pallet_of_boxes",
    "random_blob",
    "random_family_layout",
    "random_voxel_shape",
    "stairs",
    "tower",
    "voxel_layout",
    "wall",
    "with_floating",
]
