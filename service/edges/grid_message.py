"""A map over the search grid as a foxglove.Grid protobuf message, and back.

The Zenoh keys ``slim`` and ``plume`` and the MCAP grid channels carry this message, so
Foxglove's 3D panel draws the maps in place and any protobuf reader gets the numbers back.
Layout (Foxglove Grid schema): ``data`` is row-major with rows along +y, so byte offset
``i`` has its corner at ``y = i // row_stride * cell_size.y`` and
``x = (i % row_stride) // cell_stride * cell_size.x`` relative to ``pose``. With the pose at
(x_min, y_min) and identity orientation, data row 0 is the southern row, exactly row 0 of the
(n, m) map arrays, so encoding is a plain little-endian float32 dump of the array.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from foxglove_schemas_protobuf.Grid_pb2 import Grid as GridProto
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from google.protobuf.message import DecodeError

from service.core.grid import Grid

FIELD_NAME = "likelihood"
"""The one data field of every OSLIM grid message."""

SCHEMA_NAME = "foxglove.Grid"
"""Protobuf full name of the message; Foxglove recognises the schema by it."""

DEFAULT_FRAME_ID = "map"

_FLOAT32 = np.dtype("<f4")  # foxglove packed fields are little-endian
_CELL_STRIDE = _FLOAT32.itemsize


def encode_grid(
    values: npt.ArrayLike, grid: Grid, time_s: float, *, frame_id: str = DEFAULT_FRAME_ID
) -> GridProto:
    """``values`` of shape ``grid.shape`` = (n, m) as a foxglove.Grid with one float32 field.

    ``time_s`` goes into the message timestamp (seconds, the service clock).
    """
    array = np.asarray(values)
    if array.shape != grid.shape:
        raise ValueError(f"map has shape {array.shape}, grid needs {grid.shape} (rows, columns)")
    if not math.isfinite(time_s):
        raise ValueError(f"time_s must be finite, got {time_s}")
    message = GridProto(
        frame_id=frame_id,
        column_count=grid.columns,
        row_stride=grid.columns * _CELL_STRIDE,
        cell_stride=_CELL_STRIDE,
        data=np.ascontiguousarray(array, dtype=_FLOAT32).tobytes(),
    )
    seconds = math.floor(time_s)
    message.timestamp.seconds = seconds
    message.timestamp.nanos = min(round((time_s - seconds) * 1e9), 999_999_999)
    message.pose.position.x = grid.x_min
    message.pose.position.y = grid.y_min
    message.pose.position.z = 0.0
    message.pose.orientation.w = 1.0
    message.cell_size.x = grid.cell_width_m
    message.cell_size.y = grid.cell_height_m
    message.fields.add(name=FIELD_NAME, offset=0, type=PackedElementField.FLOAT32)
    return message


def grid_payload(
    values: npt.ArrayLike, grid: Grid, time_s: float, *, frame_id: str = DEFAULT_FRAME_ID
) -> bytes:
    """``encode_grid`` serialised: the bytes that go on the wire and into MCAP."""
    payload: bytes = encode_grid(values, grid, time_s, frame_id=frame_id).SerializeToString()
    return payload


def decode_grid(message: bytes | GridProto) -> npt.NDArray[np.float32]:
    """The ``likelihood`` field of a foxglove.Grid as a native float32 (rows, columns) array.

    Any strides and field offset are honoured, so grids from other producers decode too; a
    message without a float32 ``likelihood`` field or with inconsistent sizes is a ValueError.
    """
    if isinstance(message, bytes | bytearray | memoryview):
        proto = GridProto()
        try:
            proto.ParseFromString(bytes(message))
        except DecodeError as exc:
            raise ValueError(f"not a foxglove.Grid protobuf message: {exc}") from None
    else:
        proto = message
    field = next((f for f in proto.fields if f.name == FIELD_NAME), None)
    if field is None:
        raise ValueError(f"grid has no field named {FIELD_NAME!r}")
    if field.type != PackedElementField.FLOAT32:
        raise ValueError(f"grid field {FIELD_NAME!r} is not FLOAT32 (type {field.type})")
    columns, row_stride, cell_stride = proto.column_count, proto.row_stride, proto.cell_stride
    size = len(proto.data)
    if columns < 1 or cell_stride < 1 or row_stride < columns * cell_stride:
        raise ValueError(
            f"inconsistent grid layout: column_count {columns}, row_stride {row_stride}, "
            f"cell_stride {cell_stride}"
        )
    if field.offset + _CELL_STRIDE > cell_stride or size % row_stride:
        raise ValueError(f"grid data of {size} bytes does not fit row_stride {row_stride}")
    rows = size // row_stride
    if rows == 0:
        raise ValueError("grid has no data")
    view = np.ndarray(
        shape=(rows, columns),
        dtype=_FLOAT32,
        buffer=proto.data,
        offset=field.offset,
        strides=(row_stride, cell_stride),
    )
    return view.astype(np.float32)
