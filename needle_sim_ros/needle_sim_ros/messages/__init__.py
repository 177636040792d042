"""ROS message building and CDR encoding shared by the nodes (``nodes/``) and the offline pipeline (``offline/``).

``cdr``: message bytes straight from arrays (and the decoders of the offline inputs); ``shape``: NeedleShape and
ShapeError message objects; ``geometry``: the ROS-free geometry of the shape outputs (orientations along the
centerline, the tube's triangles); ``centerline_display``: the comparison's Path and Marker tube bytes.
"""
