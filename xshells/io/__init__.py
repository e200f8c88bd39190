"""Reading and writing designs (line graphs) and centerline geometry."""
from .design import Design, design_from_arrays, read_design, read_rest_lengths
from .export import write_design_obj, write_polylines_obj

__all__ = [
    "Design",
    "design_from_arrays",
    "read_design",
    "read_rest_lengths",
    "write_design_obj",
    "write_polylines_obj",
]
