"""Layout generators, one module each (import from the module you need):

* :mod:`.procedural`: seeded layout families (stairs, levers, towers,
  bridges, walls, cuboids, pallets, floating bricks);
* :mod:`.voxels`: voxel shapes and the StableLego-style merge of voxels
  into bricks;
* :mod:`.mesh`: meshes (STL, OBJ, PLY, OFF, GLB) to voxels;
* :mod:`.objects`: dataset objects made from voxels and meshes (merge,
  analyse, write).
"""
