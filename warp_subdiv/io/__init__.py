"""Reading and writing meshes: OBJ files and the USD primitives of the bake (a mesh prim's arrays, primvars, subsets and
tags; the scene's instancing structure; output layers and Vt arrays).

Only the vocabulary (errors, options, mesh) and the runtime lie below: nothing here refines. pxr is imported by the
USD modules only, so reading an OBJ file loads no USD.
"""
