"""Build arithmetic in a node tree from Python: one call per math node, constants inlined.

Shader trees and geometry-node trees share ShaderNodeMath / ShaderNodeVectorMath, so the
splat material (splat_material.py) and the splat geometry nodes (node_groups.py) both write
their formulas with `NodeMath` instead of hundreds of lines of node wiring.
"""

from __future__ import annotations

from typing import Union

Operand = Union["bpy.types.NodeSocket", float, int, tuple]  # noqa: F821  (bpy is imported by the callers)


def output(node, name: str, socket_type: str | None = None):
    """A node output by name (and type: some nodes keep one hidden output per data type)."""
    for out in node.outputs:
        if out.name == name and (socket_type is None or out.type == socket_type) and out.enabled:
            return out
    raise KeyError(f"{node.bl_idname} has no enabled output {name!r} of type {socket_type}")


def input_socket(node, name: str, socket_type: str | None = None):
    for inp in node.inputs:
        if inp.name == name and (socket_type is None or inp.type == socket_type) and inp.enabled:
            return inp
    raise KeyError(f"{node.bl_idname} has no enabled input {name!r} of type {socket_type}")


class NodeMath:
    """Math on sockets of one node tree; every method returns the result's output socket."""

    def __init__(self, tree, x: float = 0.0, y: float = 0.0):
        self.tree = tree
        self._x, self._y = x, y

    def node(self, bl_idname: str, **props):
        node = self.tree.nodes.new(bl_idname)
        node.location = (self._x, self._y)
        self._y -= 40.0
        for key, value in props.items():
            setattr(node, key, value)
        return node

    def _feed(self, sock, value) -> None:
        if isinstance(value, (int, float, tuple, list)):
            sock.default_value = value if not isinstance(value, (tuple, list)) else tuple(value)
        else:
            self.tree.links.new(value, sock)

    def math(self, operation: str, a: Operand, b: Operand = 0.0, c: Operand | None = None):
        node = self.node("ShaderNodeMath", operation=operation)
        self._feed(node.inputs[0], a)
        self._feed(node.inputs[1], b)
        if c is not None:
            self._feed(node.inputs[2], c)
        return node.outputs[0]

    def vmath(self, operation: str, a: Operand, b: Operand | None = None, scale: Operand | None = None):
        """Vector math; DOT_PRODUCT / LENGTH return the float output, SCALE takes `scale`."""
        node = self.node("ShaderNodeVectorMath", operation=operation)
        self._feed(node.inputs[0], a)
        if b is not None:
            self._feed(node.inputs[1], b)
        if scale is not None:
            self._feed(input_socket(node, "Scale"), scale)
        if operation in ("DOT_PRODUCT", "LENGTH", "DISTANCE"):
            return output(node, "Value")
        return output(node, "Vector")

    # small conveniences ---------------------------------------------------------------------
    def add(self, a, b):
        return self.math("ADD", a, b)

    def sub(self, a, b):
        return self.math("SUBTRACT", a, b)

    def mul(self, a, b):
        return self.math("MULTIPLY", a, b)

    def div(self, a, b):
        return self.math("DIVIDE", a, b)  # Blender's divide is safe: x / 0 = 0

    def separate(self, vector):
        node = self.node("ShaderNodeSeparateXYZ")
        self._feed(node.inputs[0], vector)
        return node.outputs["X"], node.outputs["Y"], node.outputs["Z"]

    def combine(self, x, y, z):
        node = self.node("ShaderNodeCombineXYZ")
        for sock, value in zip(node.inputs, (x, y, z)):
            self._feed(sock, value)
        return node.outputs[0]

    def srgb_to_linear(self, value):
        """IEC 61966-2-1 decoding of one channel (extended above 1 by the same power law)."""
        low = self.div(value, 12.92)
        high = self.math("POWER", self.div(self.add(value, 0.055), 1.055), 2.4)
        is_high = self.math("GREATER_THAN", value, 0.04045)
        return self.add(low, self.mul(is_high, self.sub(high, low)))

    def srgb_to_linear_rgb(self, vector):
        return self.combine(*(self.srgb_to_linear(c) for c in self.separate(vector)))
