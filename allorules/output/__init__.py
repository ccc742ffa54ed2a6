"""Output: meshes written in the input's own layout (UVs, materials kept), headless renders and
galleries, and offline HTML reports.
"""
