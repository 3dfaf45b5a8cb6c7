"""Reading and writing meshes: OBJ files and the USD primitives of the bake.

* :mod:`.obj`: OBJ files (and their .creases / .corners side files);
* :mod:`.files`: publishing a finished output file (the rename over the output, with the permissions of a
  new file);
* :mod:`.usd_stage`: opening a stage, the prims a run is limited to, the time samples a frame range selects;
* :mod:`.usd_read`: one mesh prim as read (its arrays, options, primvars, subsets and tags);
* :mod:`.usd_scene`: the scene's structure (instances, variants, identical meshes read once) and where each
  refined mesh goes;
* :mod:`.usd_write`: output layers and Vt arrays.

Only the vocabulary (errors, options, mesh) and the runtime lie below: nothing here refines. pxr is imported by the
USD modules only, so reading an OBJ file loads no USD; for that reason this package exports no names itself:
import them from the module that defines them.
"""
