"""An ORT-format model file (onnxruntime's flatbuffer format) rewritten as an ONNX model, in memory.

Why: moonshine-cpp ships Moonshine as ORT-format files, and onnxruntime runs such a file as saved,
without its graph optimizations. Their weights are int8, dequantized by Cast/Mul/Add nodes on every
run: in the decoder that is most of each call's ~45 ms, paid 3-8 times per utterance. The same graph
loaded as ONNX is constant-folded (the weights are dequantized once, at load) and its layer norms
and attention are fused, so a decoder call costs a fraction of that.

The flatbuffer is read with the classes onnxruntime ships (`onnxruntime.tools.ort_format_model`,
over the `flatbuffers` package, an onnxruntime dependency) and the ONNX protobuf is written by hand
(the few message types needed), so the `onnx` package is not needed. Field numbers are onnx.proto's.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from typing import Any

# ONNX AttributeProto.AttributeType; the ORT flatbuffer uses the same numbers.
_FLOAT, _INT, _STRING, _TENSOR, _GRAPH, _FLOATS, _INTS, _STRINGS, _TENSORS, _GRAPHS = (
    1, 2, 3, 4, 5, 6, 7, 8, 9, 10,
)  # fmt: skip
_TENSOR_TYPE = 1  # TypeInfoValue.tensor_type in the flatbuffer


class FormatError(ValueError):
    pass


def _varint(value: int) -> bytes:
    value &= (1 << 64) - 1  # negative int64 as two's complement, as protobuf does
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _key(field: int, wire: int) -> bytes:
    return _varint(field << 3 | wire)


def _int(field: int, value: int) -> bytes:
    return _key(field, 0) + _varint(value)


def _bytes(field: int, value: bytes) -> bytes:
    return _key(field, 2) + _varint(len(value)) + value


def _str(field: int, value: bytes | str | None) -> bytes:
    if not value:
        return b""
    return _bytes(field, value.encode() if isinstance(value, str) else value)


def _packed_ints(field: int, values: Iterable[int]) -> bytes:
    payload = b"".join(_varint(v) for v in values)
    return _bytes(field, payload) if payload else b""


def _tensor(tensor: Any) -> bytes:
    if tensor.ExternalDataOffset() >= 0:
        raise FormatError("tensors stored outside the flatbuffer are not supported")
    out = _packed_ints(1, (tensor.Dims(i) for i in range(tensor.DimsLength())))
    out += _int(2, tensor.DataType()) + _str(8, tensor.Name())
    for i in range(tensor.StringDataLength()):
        out += _bytes(6, tensor.StringData(i))
    if tensor.RawDataLength():
        out += _bytes(9, tensor.RawDataAsNumpy().tobytes())
    return out


def _value_info(arg: Any) -> bytes:
    out = _str(1, arg.Name())
    info = arg.Type()
    if info is None:
        return out
    if info.ValueType() != _TENSOR_TYPE:
        raise FormatError(f"{arg.Name()!r}: only tensor values are supported")
    from onnxruntime.tools.ort_format_model.ort_flatbuffers_py.fbs.TensorTypeAndShape import (
        TensorTypeAndShape,
    )

    table = info.Value()
    tensor_type = TensorTypeAndShape()
    tensor_type.Init(table.Bytes, table.Pos)
    body = _int(1, tensor_type.ElemType())
    shape = tensor_type.Shape()
    if shape is not None:
        dims = b""
        for i in range(shape.DimLength()):
            value = shape.Dim(i).Value()
            dim = b""
            if value is not None:
                dim = _int(1, value.DimValue()) if value.DimType() == 1 else _str(2, value.DimParam())
            dims += _bytes(1, dim)
        body += _bytes(2, dims)
    return out + _bytes(2, _bytes(1, body))


def _attribute(attribute: Any) -> bytes:
    kind = attribute.Type()
    out = _str(1, attribute.Name()) + _int(20, kind)
    if kind == _FLOAT:
        out += _key(2, 5) + struct.pack("<f", attribute.F())
    elif kind == _INT:
        out += _int(3, attribute.I())
    elif kind == _STRING:
        out += _bytes(4, attribute.S() or b"")
    elif kind == _TENSOR:
        out += _bytes(5, _tensor(attribute.T()))
    elif kind == _GRAPH:
        out += _bytes(6, _graph(attribute.G(), "subgraph"))
    elif kind == _FLOATS:
        values = [attribute.Floats(i) for i in range(attribute.FloatsLength())]
        out += _bytes(7, struct.pack(f"<{len(values)}f", *values)) if values else b""
    elif kind == _INTS:
        out += _packed_ints(8, (attribute.Ints(i) for i in range(attribute.IntsLength())))
    elif kind == _STRINGS:
        for i in range(attribute.StringsLength()):
            out += _bytes(9, attribute.Strings(i))
    elif kind == _TENSORS:
        for i in range(attribute.TensorsLength()):
            out += _bytes(10, _tensor(attribute.Tensors(i)))
    elif kind == _GRAPHS:
        for i in range(attribute.GraphsLength()):
            out += _bytes(11, _graph(attribute.Graphs(i), "subgraph"))
    else:
        raise FormatError(f"attribute {attribute.Name()!r} has unsupported type {kind}")
    return out


def _node(node: Any) -> bytes:
    out = b"".join(_bytes(1, node.Inputs(i)) for i in range(node.InputsLength()))
    out += b"".join(_bytes(2, node.Outputs(i)) for i in range(node.OutputsLength()))
    out += _str(3, node.Name()) + _str(4, node.OpType())
    out += b"".join(_bytes(5, _attribute(node.Attributes(i))) for i in range(node.AttributesLength()))
    return out + _str(7, node.Domain())


def _graph(graph: Any, name: str) -> bytes:
    if graph.SparseInitializersLength():
        raise FormatError("sparse initializers are not supported")
    args = {graph.NodeArgs(i).Name(): graph.NodeArgs(i) for i in range(graph.NodeArgsLength())}
    inputs = [graph.Inputs(i) for i in range(graph.InputsLength())]
    outputs = [graph.Outputs(i) for i in range(graph.OutputsLength())]
    nodes = sorted(
        (graph.Nodes(i) for i in range(graph.NodesLength())), key=lambda node: node.Index()
    )  # ORT sorts them topologically itself
    parts = [_bytes(1, _node(node)) for node in nodes]
    parts.append(_str(2, name))
    parts += [_bytes(5, _tensor(graph.Initializers(i))) for i in range(graph.InitializersLength())]
    for field, names in ((11, inputs), (12, outputs)):
        for arg_name in names:
            if arg_name not in args:
                raise FormatError(f"graph {'input' if field == 11 else 'output'} {arg_name!r} has no type")
            parts.append(_bytes(field, _value_info(args[arg_name])))
    ends = set(inputs) | set(outputs)
    parts += [_bytes(13, _value_info(arg)) for key, arg in args.items() if key not in ends]
    return b"".join(parts)  # joined once: the initializers are tens of MB


def onnx_model(ort_bytes: bytes) -> bytes:
    """The ONNX ModelProto of an ORT-format model (its runtime optimizations records dropped)."""
    from onnxruntime.tools.ort_format_model.ort_flatbuffers_py.fbs.InferenceSession import (
        InferenceSession,
    )

    if not InferenceSession.InferenceSessionBufferHasIdentifier(ort_bytes, 0):
        raise FormatError("not an ORT-format model")
    model = InferenceSession.GetRootAs(ort_bytes, 0).Model()
    if model is None or model.Graph() is None:
        raise FormatError("the file holds no model")
    out = _int(1, model.IrVersion())
    for i in range(model.OpsetImportLength()):
        opset = model.OpsetImport(i)
        out += _bytes(8, _str(1, opset.Domain()) + _int(2, opset.Version()))
    out += _str(2, model.ProducerName()) + _str(3, model.ProducerVersion())
    return out + _bytes(7, _graph(model.Graph(), "main"))
