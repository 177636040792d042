"""ROS messages shared by the nodes (``nodes/``) and the offline pipeline (``offline/``): ``cdr`` encodes them from
arrays; ``shape``: needle shapes, shape errors, stamps; ``geometry``: the ROS-free geometry of the shape outputs
(tangents, the tube's triangles); ``centerline_display``: the comparison's Path and Marker tube bytes.
"""
