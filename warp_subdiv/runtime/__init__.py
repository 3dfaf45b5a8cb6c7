"""The process around a refinement: worker threads, phase timing, memory estimates and the allocator's settings.

Nothing here knows a mesh or a rule; every other floor may use it.
"""
