"""The robot model: a URDF read as ROS reads it, into the immutable :class:`RobotModel` every
computation shares.

- :mod:`.types`: :class:`RobotModel`, :class:`ParentJoint`, :class:`JointKind`.
- :mod:`.document`: the XML parsed by lxml, accepted where urdfdom's TinyXML2 accepts it.
- :mod:`.reader`: yourdfpy, the URDF library, imported quietly when a model is first loaded.
- :mod:`.xacro`: whether a description needs xacro, and its expansion.
- :mod:`.urdf`: the links and joints of a URDF, read by yourdfpy, by urdfdom's rules.
- :mod:`.build`: the checked tree, its root and joint columns; what is refused, what is warned.
- :mod:`.load`: :func:`load_model`.
- :mod:`.payload`: :func:`with_payload`, a point mass the URDF does not have.
"""

from neforward_ros.model.load import description_text, load_model
from neforward_ros.model.payload import with_payload
from neforward_ros.model.types import JointKind, Mat3, ParentJoint, RobotModel, Vec3

__all__ = ["JointKind", "Mat3", "ParentJoint", "RobotModel", "Vec3", "description_text", "load_model", "with_payload"]
