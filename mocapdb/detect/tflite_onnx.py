"""TFLite → ONNX: mocapdb's own converter for MediaPipe's float models (BlazePose's person detector and
landmarks, the hand and face landmarks).

The TFLite flatbuffer is read with the ``tflite`` package (the schema's generated readers) and the
same graph written with ``onnx`` (opset :data:`OPSET`). Operators covered: CONV_2D,
DEPTHWISE_CONV_2D, MAX_POOL_2D, ADD, PAD, PRELU, RESIZE_BILINEAR, DEPTH_TO_SPACE, RESHAPE, CONCATENATION,
LOGISTIC, MEAN (over constant axes), FULLY_CONNECTED (2-D input, float weights), with their fused
activations (RELU, RELU6); DEQUANTIZE and DENSIFY of constant weights
(float16, stored dense or sparse) are evaluated here, so the ONNX file holds float32 weights only.

TFLite tensors are NHWC; the ONNX graph computes in NCHW: the input is transposed once, every 4-D
tensor stays NCHW inside the graph, a RESHAPE sees its input back in NHWC, and 4-D outputs are
transposed back, so inputs and outputs keep the TFLite shapes. Anything else (quantised int8
models, other operators, several subgraphs) is refused with :class:`ConversionError` naming it.
Decisions: ``data_specs/pose_models.md`` ("BlazePose").
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

OPSET = 13
NHWC_TO_NCHW = (0, 3, 1, 2)
NCHW_TO_NHWC = (0, 2, 3, 1)
_AXIS_NHWC_TO_NCHW = {0: 0, 1: 2, 2: 3, 3: 1}
# TensorType codes of the TFLite schema → numpy
_DTYPES = {0: np.float32, 1: np.float16, 2: np.int32, 3: np.uint8, 4: np.int64, 9: np.int8}
_ACTIVATIONS = {0: None, 1: "relu", 3: "relu6"}   # ActivationFunctionType codes handled
_SAME, _VALID = 0, 1                              # Padding codes


class ConversionError(ValueError):
    """A TFLite model this converter does not handle (names the operator or tensor)."""


@dataclass
class _Graph:
    """The ONNX graph being written: nodes, initialisers and a name for each TFLite tensor."""

    nodes: list = field(default_factory=list)
    initializers: list = field(default_factory=list)
    count: int = 0

    def fresh(self, hint: str) -> str:
        self.count += 1
        return f"{hint}__{self.count}"

    def constant(self, array: np.ndarray | np.generic, hint: str) -> str:
        from onnx import numpy_helper
        name = self.fresh(hint)
        self.initializers.append(numpy_helper.from_array(np.ascontiguousarray(array), name))
        return name

    def node(self, op: str, inputs: list[str], hint: str, output: str | None = None, **attrs) -> str:
        from onnx import helper
        output = output or self.fresh(hint)
        self.nodes.append(helper.make_node(op, inputs, [output], name=self.fresh(op), **attrs))
        return output


# --- reading the flatbuffer -----------------------------------------------------------------------

def _operator_names() -> dict[int, str]:
    import tflite
    return {v: k for k, v in vars(tflite.BuiltinOperator).items() if not k.startswith("_")}


def _options(op, kind: str):
    """The builtin options table of ``op`` read as ``tflite.<kind>``."""
    import tflite
    table = op.BuiltinOptions()
    options = getattr(tflite, kind)()
    options.Init(table.Bytes, table.Pos)
    return options


def _densify(values: np.ndarray, tensor) -> np.ndarray:
    """A sparse constant (TFLite SparsityParameters: dense/CSR dimensions in traversal order, optional
    blocks) → its dense array."""
    sparsity = tensor.Sparsity()
    shape = tuple(int(s) for s in tensor.ShapeAsNumpy())
    order = sparsity.TraversalOrderAsNumpy().astype(int)
    block_map = sparsity.BlockMapAsNumpy() if sparsity.BlockMapLength() else np.zeros(0, dtype=int)
    positions = np.zeros(1, dtype=np.int64)
    coords = np.zeros((1, 0), dtype=np.int64)
    for level in range(sparsity.DimMetadataLength()):
        meta = sparsity.DimMetadata(level)
        if meta.Format() == 0:   # DENSE
            size = meta.DenseSize()
            positions = (positions[:, None] * size + np.arange(size)).ravel()
            coords = np.concatenate([np.repeat(coords, size, axis=0),
                                     np.tile(np.arange(size), len(coords))[:, None]], axis=1)
        else:                     # SPARSE_CSR
            segments, indices = _index_vector(meta.ArraySegments(), meta.ArraySegmentsType()), \
                _index_vector(meta.ArrayIndices(), meta.ArrayIndicesType())
            starts, ends = segments[positions], segments[positions + 1]
            counts = ends - starts
            parent = np.repeat(np.arange(len(positions)), counts)
            positions = np.concatenate([np.arange(s, e) for s, e in zip(starts, ends)]).astype(np.int64) \
                if counts.sum() else np.zeros(0, dtype=np.int64)
            coords = np.concatenate([coords[parent], indices[positions][:, None]], axis=1)
    dense = np.zeros(shape, dtype=values.dtype)
    original = np.zeros((len(coords), len(shape)), dtype=np.int64)
    for level, dim in enumerate(order):
        if dim < len(shape):
            original[:, dim] += coords[:, level]
    for k, dim in enumerate(block_map):   # block dimensions: offset within the block
        level = int(np.flatnonzero(order == len(shape) + k)[0])
        block = sparsity.DimMetadata(level).DenseSize()
        original[:, dim] = original[:, dim] * block + coords[:, level]
    dense[tuple(original.T)] = values[positions]
    return dense


def _index_vector(table, kind: int) -> np.ndarray:
    """A SparseIndexVector union (Int32Vector 1, Uint16Vector 2, Uint8Vector 3) → int64 array."""
    import tflite
    vector = {1: tflite.Int32Vector, 2: tflite.Uint16Vector, 3: tflite.Uint8Vector}[kind]()
    vector.Init(table.Bytes, table.Pos)
    return vector.ValuesAsNumpy().astype(np.int64)


class _Reader:
    """One TFLite model's single subgraph: tensors, constants (evaluated), operators."""

    def __init__(self, path: Path) -> None:
        import tflite
        self.model = tflite.Model.GetRootAsModel(Path(path).read_bytes(), 0)
        if self.model.SubgraphsLength() != 1:
            raise ConversionError(f"{path}: {self.model.SubgraphsLength()} subgraphs (one expected)")
        self.graph = self.model.Subgraphs(0)
        self.names = _operator_names()
        self.constants: dict[int, np.ndarray] = {}

    def tensor(self, index: int):
        return self.graph.Tensors(index)

    def shape(self, index: int) -> tuple[int, ...]:
        return tuple(int(s) for s in self.tensor(index).ShapeAsNumpy())

    def constant(self, index: int) -> np.ndarray | None:
        """The value of a constant tensor (a buffer of its own, or one evaluated here); else None."""
        if index in self.constants:
            return self.constants[index]
        tensor = self.tensor(index)
        data = self.model.Buffers(tensor.Buffer()).DataAsNumpy()
        if isinstance(data, int) or data.size == 0:
            return None
        if tensor.Type() not in _DTYPES:
            raise ConversionError(f"tensor {tensor.Name().decode()}: type code {tensor.Type()} not handled")
        values = np.frombuffer(data.tobytes(), dtype=_DTYPES[tensor.Type()])
        array = _densify(values, tensor) if tensor.Sparsity() is not None else \
            values.reshape(self.shape(index))
        self.constants[index] = array
        return array

    def weights(self, index: int, what: str) -> np.ndarray:
        """The value of constant tensor ``index``, ``what`` an operator reads (ConversionError if computed)."""
        array = self.constant(index)
        if array is None:
            raise ConversionError(f"{what} of a computed tensor {self.tensor(index).Name().decode()} "
                                  "(only constant ones are handled)")
        return array

    def operators(self):
        for i in range(self.graph.OperatorsLength()):
            op = self.graph.Operators(i)
            code = self.model.OperatorCodes(op.OpcodeIndex())
            name = self.names.get(max(code.BuiltinCode(), code.DeprecatedBuiltinCode()), "CUSTOM")
            yield name, op, [op.Inputs(j) for j in range(op.InputsLength())], \
                [op.Outputs(j) for j in range(op.OutputsLength())]


# --- operators ------------------------------------------------------------------------------------

def _same_pads(size_hw: Sequence[int], kernel_hw: Sequence[int], stride_hw: Sequence[int],
               dilation_hw: Sequence[int] = (1, 1)) -> list[int]:
    """ONNX pads [top, left, bottom, right] of TFLite's SAME padding (the extra pixel after)."""
    before, after = [], []
    for size, k, s, d in zip(size_hw, kernel_hw, stride_hw, dilation_hw):
        out = -(-size // s)
        total = max((out - 1) * s + (k - 1) * d + 1 - size, 0)
        before.append(total // 2)
        after.append(total - total // 2)
    return before + after


class _Converter:
    """Walks the TFLite operators in order, writing each as ONNX nodes (module docstring)."""

    def __init__(self, reader: _Reader) -> None:
        self.r = reader
        self.g = _Graph()
        self.names: dict[int, str] = {}   # TFLite tensor → ONNX value (4-D ones in NCHW)

    def value(self, index: int) -> str:
        if index in self.names:
            return self.names[index]
        array = self.r.constant(index)
        if array is None:
            raise ConversionError(f"tensor {self.r.tensor(index).Name().decode()} used before it is computed")
        if array.ndim == 4:
            array = array.transpose(NHWC_TO_NCHW)
        self.names[index] = self.g.constant(array.astype(np.float32) if array.dtype == np.float16 else array,
                                            "const")
        return self.names[index]

    def activate(self, name: str, code: int, output: str) -> str:
        if code not in _ACTIVATIONS:
            raise ConversionError(f"fused activation code {code} not handled")
        kind = _ACTIVATIONS[code]
        if kind is None:
            return self.g.node("Identity", [name], "id", output)
        if kind == "relu":
            return self.g.node("Relu", [name], "relu", output)
        low, high = self.g.constant(np.float32(0.0), "zero"), self.g.constant(np.float32(6.0), "six")
        return self.g.node("Clip", [name, low, high], "relu6", output)

    def out_name(self, index: int) -> str:
        return self.r.tensor(index).Name().decode() + "__nchw"

    def convert(self, name: str, op, inputs: list[int], outputs: list[int]) -> None:
        if name in ("DEQUANTIZE", "DENSIFY"):
            source = self.r.constant(inputs[0])
            if source is None:
                raise ConversionError(f"{name} of a computed tensor (only constant weights are handled)")
            self.r.constants[outputs[0]] = source.astype(np.float32) if name == "DEQUANTIZE" else source
            return
        handler = getattr(self, f"_{name.lower()}", None)
        if handler is None:
            raise ConversionError(f"operator {name} not handled")
        handler(op, inputs, outputs[0])

    def _conv_2d(self, op, inputs, output) -> None:
        o = _options(op, "Conv2DOptions")
        weights = self.r.weights(inputs[1], "CONV_2D weights").astype(np.float32)
        weights = weights.transpose(0, 3, 1, 2)   # [O, I, kh, kw]
        self._conv(op, inputs, output, weights, 1, o)

    def _depthwise_conv_2d(self, op, inputs, output) -> None:
        o = _options(op, "DepthwiseConv2DOptions")
        weights = self.r.weights(inputs[1], "DEPTHWISE_CONV_2D weights").astype(np.float32)  # [1, kh, kw, C·m]
        weights = weights.transpose(3, 0, 1, 2)                      # [C·m, 1, kh, kw]
        self._conv(op, inputs, output, weights, self.r.shape(inputs[0])[3], o)

    def _conv(self, op, inputs, output, weights: np.ndarray, group: int, o) -> None:
        size_hw = self.r.shape(inputs[0])[1:3]
        kernel_hw, stride_hw = weights.shape[2:], (o.StrideH(), o.StrideW())
        dilation_hw = (o.DilationHFactor(), o.DilationWFactor())
        pads = _same_pads(size_hw, kernel_hw, stride_hw, dilation_hw) if o.Padding() == _SAME else [0, 0, 0, 0]
        args = [self.value(inputs[0]), self.g.constant(weights, "w")]
        if len(inputs) > 2 and inputs[2] >= 0:
            args.append(self.g.constant(self.r.weights(inputs[2], "a convolution's bias").astype(np.float32), "b"))
        conv = self.g.node("Conv", args, "conv", kernel_shape=list(kernel_hw), strides=list(stride_hw),
                           dilations=list(dilation_hw), pads=pads, group=group)
        self.names[output] = self.activate(conv, o.FusedActivationFunction(), self.out_name(output))

    def _max_pool_2d(self, op, inputs, output) -> None:
        o = _options(op, "Pool2DOptions")
        kernel_hw, stride_hw = (o.FilterHeight(), o.FilterWidth()), (o.StrideH(), o.StrideW())
        size_hw = self.r.shape(inputs[0])[1:3]
        pads = _same_pads(size_hw, kernel_hw, stride_hw) if o.Padding() == _SAME else [0, 0, 0, 0]
        pool = self.g.node("MaxPool", [self.value(inputs[0])], "pool", kernel_shape=list(kernel_hw),
                           strides=list(stride_hw), pads=pads)
        self.names[output] = self.activate(pool, o.FusedActivationFunction(), self.out_name(output))

    def _add(self, op, inputs, output) -> None:
        o = _options(op, "AddOptions")
        add = self.g.node("Add", [self._broadcast(inputs[0], output), self._broadcast(inputs[1], output)], "add")
        self.names[output] = self.activate(add, o.FusedActivationFunction(), self.out_name(output))

    def _broadcast(self, index: int, output: int) -> str:
        """A constant operand of lower rank than a 4-D result, made NCHW-broadcastable."""
        array = self.r.constant(index) if index not in self.names else None
        if array is not None and array.ndim < 4 and len(self.r.shape(output)) == 4:
            full = array.astype(np.float32).reshape((1,) * (4 - array.ndim) + array.shape)
            return self.g.constant(full.transpose(NHWC_TO_NCHW), "bcast")
        return self.value(index)

    def _prelu(self, op, inputs, output) -> None:
        slope = self._broadcast(inputs[1], output)
        self.names[output] = self.g.node("PRelu", [self.value(inputs[0]), slope], "prelu", self.out_name(output))

    def _logistic(self, op, inputs, output) -> None:
        self.names[output] = self.g.node("Sigmoid", [self.value(inputs[0])], "sigmoid", self.out_name(output))

    def _pad(self, op, inputs, output) -> None:
        paddings = self.r.weights(inputs[1], "PAD paddings").astype(np.int64)  # [rank, 2] before/after per dim
        if len(paddings) == 4:
            paddings = paddings[list(NHWC_TO_NCHW)]
        pads = np.concatenate([paddings[:, 0], paddings[:, 1]])
        self.names[output] = self.g.node("Pad", [self.value(inputs[0]), self.g.constant(pads, "pads")], "pad",
                                         self.out_name(output), mode="constant")

    def _resize_bilinear(self, op, inputs, output) -> None:
        o = _options(op, "ResizeBilinearOptions")
        mode = "align_corners" if o.AlignCorners() else "half_pixel" if o.HalfPixelCenters() else "asymmetric"
        n, _, _, c = self.r.shape(inputs[0])
        height, width = (int(v) for v in self.r.weights(inputs[1], "RESIZE_BILINEAR size"))
        sizes = self.g.constant(np.array([n, c, height, width], dtype=np.int64), "sizes")
        self.names[output] = self.g.node("Resize", [self.value(inputs[0]), "", "", sizes], "resize",
                                         self.out_name(output), mode="linear",
                                         coordinate_transformation_mode=mode)

    def _depth_to_space(self, op, inputs, output) -> None:
        o = _options(op, "DepthToSpaceOptions")
        self.names[output] = self.g.node("DepthToSpace", [self.value(inputs[0])], "d2s", self.out_name(output),
                                         blocksize=o.BlockSize(), mode="DCR")

    def _reshape(self, op, inputs, output) -> None:
        source = self.value(inputs[0])
        if len(self.r.shape(inputs[0])) == 4:
            source = self.g.node("Transpose", [source], "nhwc", perm=list(NCHW_TO_NHWC))
        shape = np.array(self.r.shape(output), dtype=np.int64)
        reshaped = self.g.node("Reshape", [source, self.g.constant(shape, "shape")], "reshape")
        if len(shape) == 4:
            reshaped = self.g.node("Transpose", [reshaped], "nchw", perm=list(NHWC_TO_NCHW))
        self.names[output] = reshaped

    def _concatenation(self, op, inputs, output) -> None:
        o = _options(op, "ConcatenationOptions")
        rank = len(self.r.shape(output))
        axis = o.Axis() % rank
        axis = _AXIS_NHWC_TO_NCHW[axis] if rank == 4 else axis
        concat = self.g.node("Concat", [self.value(i) for i in inputs], "concat", axis=axis)
        self.names[output] = self.activate(concat, o.FusedActivationFunction(), self.out_name(output))

    def _mean(self, op, inputs, output) -> None:
        keep = bool(_options(op, "ReducerOptions").KeepDims())
        rank = len(self.r.shape(inputs[0]))
        axes = sorted(int(a) % rank for a in np.ravel(self.r.weights(inputs[1], "MEAN axes")))
        if rank == 4:
            axes = sorted(_AXIS_NHWC_TO_NCHW[a] for a in axes)
            if not keep and 1 not in axes and ({2, 3} - set(axes)):
                raise ConversionError("MEAN keeping channels and a spatial axis of a 4-D tensor without keep_dims")
        self.names[output] = self.g.node("ReduceMean", [self.value(inputs[0])], "mean", self.out_name(output),
                                         axes=axes, keepdims=int(keep))

    def _fully_connected(self, op, inputs, output) -> None:
        o = _options(op, "FullyConnectedOptions")
        if len(self.r.shape(inputs[0])) != 2 or o.WeightsFormat() != 0:
            raise ConversionError("FULLY_CONNECTED of other than a 2-D input with float weights")
        weights = self.r.weights(inputs[1], "FULLY_CONNECTED weights").astype(np.float32)   # [out, in]
        args = [self.value(inputs[0]), self.g.constant(weights, "w")]
        if len(inputs) > 2 and inputs[2] >= 0:
            args.append(self.g.constant(self.r.weights(inputs[2], "FULLY_CONNECTED bias").astype(np.float32), "b"))
        gemm = self.g.node("Gemm", args, "dense", transB=1)
        self.names[output] = self.activate(gemm, o.FusedActivationFunction(), self.out_name(output))


def convert_tflite(tflite_path: Path, onnx_path: Path, doc: str = "") -> None:
    """Writes the ONNX equivalent of the float TFLite model ``tflite_path`` to ``onnx_path`` (inputs and
    outputs keep their TFLite names, shapes and NHWC order); ConversionError for what is not handled."""
    import onnx
    from onnx import TensorProto, helper

    reader = _Reader(tflite_path)
    conv = _Converter(reader)
    graph = reader.graph
    inputs = []
    for i in range(graph.InputsLength()):
        index = graph.Inputs(i)
        name, shape = reader.tensor(index).Name().decode(), reader.shape(index)
        inputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, list(shape)))
        conv.names[index] = conv.g.node("Transpose", [name], "nchw", perm=list(NHWC_TO_NCHW)) \
            if len(shape) == 4 else name
    for name, op, op_inputs, op_outputs in reader.operators():
        conv.convert(name, op, op_inputs, op_outputs)
    outputs = []
    for i in range(graph.OutputsLength()):
        index = graph.Outputs(i)
        name, shape = reader.tensor(index).Name().decode(), reader.shape(index)
        if len(shape) == 4:
            conv.g.node("Transpose", [conv.names[index]], "nhwc", name, perm=list(NCHW_TO_NHWC))
        else:
            conv.g.node("Identity", [conv.names[index]], "out", name)
        outputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, list(shape)))
    model = helper.make_model(helper.make_graph(conv.g.nodes, Path(tflite_path).stem, inputs, outputs,
                                                conv.g.initializers),
                              opset_imports=[helper.make_opsetid("", OPSET)], producer_name="mocapdb",
                              doc_string=doc)
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(onnx_path))
