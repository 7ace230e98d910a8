import numpy as np
import pytest
from foxglove_schemas_protobuf.Grid_pb2 import Grid as GridProto
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField

from service.core.grid import Grid
from service.edges.grid_message import decode_grid, encode_grid, grid_payload

# n = 7 rows, m = 11 columns: a transposition cannot go unnoticed
GRID = Grid(x_min=-10.0, x_max=12.0, y_min=100.0, y_max=114.0, columns=11, rows=7)


def test_round_trip_is_bit_exact_for_float32() -> None:
    rng = np.random.default_rng(5)
    values = rng.random(GRID.shape).astype(np.float32)
    values[0, 0] = np.float32(1e-45)  # subnormal
    values[0, 1] = np.float32(-0.0)
    values[6, 10] = np.finfo(np.float32).max
    decoded = decode_grid(grid_payload(values, GRID, 3.0))
    assert decoded.shape == (7, 11)
    assert decoded.dtype == np.float32
    assert np.array_equal(decoded.view(np.uint32), values.view(np.uint32))


def test_float64_maps_are_rounded_to_float32() -> None:
    values = np.full(GRID.shape, 1.0 / 3.0)
    decoded = decode_grid(encode_grid(values, GRID, 0.0))
    assert np.array_equal(decoded, values.astype(np.float32))


def test_layout_fields_follow_the_foxglove_grid_schema() -> None:
    message = encode_grid(np.zeros(GRID.shape), GRID, 12.25)
    assert message.frame_id == "map"
    assert message.column_count == 11
    assert message.cell_stride == 4
    assert message.row_stride == 44
    assert len(message.data) == 7 * 44
    assert (message.cell_size.x, message.cell_size.y) == (2.0, 2.0)
    position, q = message.pose.position, message.pose.orientation
    assert (position.x, position.y, position.z) == (-10.0, 100.0, 0.0)
    assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0)
    [field] = message.fields
    assert (field.name, field.offset, field.type) == ("likelihood", 0, PackedElementField.FLOAT32)
    assert (message.timestamp.seconds, message.timestamp.nanos) == (12, 250_000_000)
    assert encode_grid(np.zeros(GRID.shape), GRID, 0.0, frame_id="local").frame_id == "local"


@pytest.mark.parametrize(("x", "y"), [(-9.0, 101.0), (11.5, 113.5), (0.3, 107.9), (-10.0, 114.0)])
def test_a_cell_lands_where_foxglove_draws_it(x: float, y: float) -> None:
    """Foxglove: the element at byte offset i has its corner nearest the pose origin at
    (i % row_stride) / cell_stride * cell_size.x, i / row_stride * cell_size.y. The cell the
    grid assigns to (x, y) must be drawn as the rectangle holding (x, y): row 0 is south."""
    values = np.zeros(GRID.shape)
    values.flat[GRID.cell_of(x, y)] = 1.0
    message = encode_grid(values, GRID, 0.0)
    data = np.frombuffer(message.data, dtype="<f4")
    [index] = np.flatnonzero(data)
    i = int(index) * message.cell_stride
    corner_x = message.pose.position.x + (i % message.row_stride) // message.cell_stride * message.cell_size.x
    corner_y = message.pose.position.y + i // message.row_stride * message.cell_size.y
    assert corner_x <= x <= corner_x + message.cell_size.x
    assert corner_y <= y <= corner_y + message.cell_size.y


def test_decode_honours_strides_and_field_offset_of_other_producers() -> None:
    """Two float32 fields per cell (``other`` first) and padded rows."""
    expected = np.arange(6, dtype=np.float32).reshape(2, 3) + 0.5
    cells = np.zeros((2, 3, 2), dtype="<f4")
    cells[..., 0] = -1.0
    cells[..., 1] = expected
    rows = np.zeros((2, 3 * 8 + 4), dtype=np.uint8)  # 4 bytes of row padding
    rows[:, :24] = cells.view(np.uint8).reshape(2, 24)
    message = GridProto(column_count=3, cell_stride=8, row_stride=28, data=rows.tobytes())
    message.fields.add(name="other", offset=0, type=PackedElementField.FLOAT32)
    message.fields.add(name="likelihood", offset=4, type=PackedElementField.FLOAT32)
    assert np.array_equal(decode_grid(message.SerializeToString()), expected)


def test_encode_refuses_a_map_of_the_wrong_shape() -> None:
    with pytest.raises(ValueError, match=r"\(7, 11\)"):
        encode_grid(np.zeros((11, 7)), GRID, 0.0)


def test_decode_refuses_what_is_not_an_oslim_grid() -> None:
    with pytest.raises(ValueError, match=r"foxglove\.Grid"):
        decode_grid(b'{"time_s": 1.0}')
    message = encode_grid(np.zeros(GRID.shape), GRID, 0.0)
    message.fields[0].name = "occupancy"
    with pytest.raises(ValueError, match="no field named 'likelihood'"):
        decode_grid(message)
    message.fields[0].name = "likelihood"
    message.fields[0].type = PackedElementField.UINT8
    with pytest.raises(ValueError, match="not FLOAT32"):
        decode_grid(message)
    message.fields[0].type = PackedElementField.FLOAT32
    message.data = message.data[:-1]
    with pytest.raises(ValueError, match="does not fit"):
        decode_grid(message)
