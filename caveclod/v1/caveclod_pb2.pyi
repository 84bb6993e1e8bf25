from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class VertexEncoding(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    VERTEX_ENCODING_UNSPECIFIED: _ClassVar[VertexEncoding]
    VERTEX_ENCODING_FLOAT32: _ClassVar[VertexEncoding]
    VERTEX_ENCODING_PACKED: _ClassVar[VertexEncoding]

class FrameEncoding(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    FRAME_ENCODING_UNSPECIFIED: _ClassVar[FrameEncoding]
    FRAME_ENCODING_RAW: _ClassVar[FrameEncoding]
    FRAME_ENCODING_OPS: _ClassVar[FrameEncoding]
    FRAME_ENCODING_OPS_LINKED: _ClassVar[FrameEncoding]

class CacheStrategy(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    CACHE_STRATEGY_UNSPECIFIED: _ClassVar[CacheStrategy]
    CACHE_STRATEGY_FA: _ClassVar[CacheStrategy]
    CACHE_STRATEGY_LRU: _ClassVar[CacheStrategy]
    CACHE_STRATEGY_LRU_PQ: _ClassVar[CacheStrategy]

class KeyframeReason(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    KEYFRAME_REASON_UNSPECIFIED: _ClassVar[KeyframeReason]
    KEYFRAME_REASON_CHECKSUM_MISMATCH: _ClassVar[KeyframeReason]
    KEYFRAME_REASON_BAD_FRAME: _ClassVar[KeyframeReason]
    KEYFRAME_REASON_CLIENT_RESET: _ClassVar[KeyframeReason]

class VertexLayout(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    VERTEX_LAYOUT_UNSPECIFIED: _ClassVar[VertexLayout]
    VERTEX_LAYOUT_PLANAR: _ClassVar[VertexLayout]
    VERTEX_LAYOUT_INTERLEAVED: _ClassVar[VertexLayout]

class AttributeSemantic(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    ATTRIBUTE_SEMANTIC_UNSPECIFIED: _ClassVar[AttributeSemantic]
    ATTRIBUTE_SEMANTIC_POSITION: _ClassVar[AttributeSemantic]
    ATTRIBUTE_SEMANTIC_NORMAL: _ClassVar[AttributeSemantic]
    ATTRIBUTE_SEMANTIC_TEXCOORD: _ClassVar[AttributeSemantic]
    ATTRIBUTE_SEMANTIC_COLOR: _ClassVar[AttributeSemantic]
    ATTRIBUTE_SEMANTIC_MORPH_TARGET: _ClassVar[AttributeSemantic]

class ScalarType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SCALAR_TYPE_UNSPECIFIED: _ClassVar[ScalarType]
    SCALAR_TYPE_FLOAT32: _ClassVar[ScalarType]
    SCALAR_TYPE_UINT8: _ClassVar[ScalarType]
    SCALAR_TYPE_UINT32: _ClassVar[ScalarType]
VERTEX_ENCODING_UNSPECIFIED: VertexEncoding
VERTEX_ENCODING_FLOAT32: VertexEncoding
VERTEX_ENCODING_PACKED: VertexEncoding
FRAME_ENCODING_UNSPECIFIED: FrameEncoding
FRAME_ENCODING_RAW: FrameEncoding
FRAME_ENCODING_OPS: FrameEncoding
FRAME_ENCODING_OPS_LINKED: FrameEncoding
CACHE_STRATEGY_UNSPECIFIED: CacheStrategy
CACHE_STRATEGY_FA: CacheStrategy
CACHE_STRATEGY_LRU: CacheStrategy
CACHE_STRATEGY_LRU_PQ: CacheStrategy
KEYFRAME_REASON_UNSPECIFIED: KeyframeReason
KEYFRAME_REASON_CHECKSUM_MISMATCH: KeyframeReason
KEYFRAME_REASON_BAD_FRAME: KeyframeReason
KEYFRAME_REASON_CLIENT_RESET: KeyframeReason
VERTEX_LAYOUT_UNSPECIFIED: VertexLayout
VERTEX_LAYOUT_PLANAR: VertexLayout
VERTEX_LAYOUT_INTERLEAVED: VertexLayout
ATTRIBUTE_SEMANTIC_UNSPECIFIED: AttributeSemantic
ATTRIBUTE_SEMANTIC_POSITION: AttributeSemantic
ATTRIBUTE_SEMANTIC_NORMAL: AttributeSemantic
ATTRIBUTE_SEMANTIC_TEXCOORD: AttributeSemantic
ATTRIBUTE_SEMANTIC_COLOR: AttributeSemantic
ATTRIBUTE_SEMANTIC_MORPH_TARGET: AttributeSemantic
SCALAR_TYPE_UNSPECIFIED: ScalarType
SCALAR_TYPE_FLOAT32: ScalarType
SCALAR_TYPE_UINT8: ScalarType
SCALAR_TYPE_UINT32: ScalarType

class ClientMessage(_message.Message):
    __slots__ = ("open", "pose", "ack", "keyframe_request", "close")
    OPEN_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    ACK_FIELD_NUMBER: _ClassVar[int]
    KEYFRAME_REQUEST_FIELD_NUMBER: _ClassVar[int]
    CLOSE_FIELD_NUMBER: _ClassVar[int]
    open: Open
    pose: CameraPose
    ack: Ack
    keyframe_request: KeyframeRequest
    close: Close
    def __init__(self, open: _Optional[_Union[Open, _Mapping]] = ..., pose: _Optional[_Union[CameraPose, _Mapping]] = ..., ack: _Optional[_Union[Ack, _Mapping]] = ..., keyframe_request: _Optional[_Union[KeyframeRequest, _Mapping]] = ..., close: _Optional[_Union[Close, _Mapping]] = ...) -> None: ...

class Open(_message.Message):
    __slots__ = ("mesh", "options", "cameras", "vertex_buffer_hash", "resume_token", "last_frame_seq", "ack_window", "client", "cache_vertices", "cache_strategy", "cache_pq_fraction", "frame_encoding", "vertex_encoding", "position_bits", "morph_targets")
    MESH_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    CAMERAS_FIELD_NUMBER: _ClassVar[int]
    VERTEX_BUFFER_HASH_FIELD_NUMBER: _ClassVar[int]
    RESUME_TOKEN_FIELD_NUMBER: _ClassVar[int]
    LAST_FRAME_SEQ_FIELD_NUMBER: _ClassVar[int]
    ACK_WINDOW_FIELD_NUMBER: _ClassVar[int]
    CLIENT_FIELD_NUMBER: _ClassVar[int]
    CACHE_VERTICES_FIELD_NUMBER: _ClassVar[int]
    CACHE_STRATEGY_FIELD_NUMBER: _ClassVar[int]
    CACHE_PQ_FRACTION_FIELD_NUMBER: _ClassVar[int]
    FRAME_ENCODING_FIELD_NUMBER: _ClassVar[int]
    VERTEX_ENCODING_FIELD_NUMBER: _ClassVar[int]
    POSITION_BITS_FIELD_NUMBER: _ClassVar[int]
    MORPH_TARGETS_FIELD_NUMBER: _ClassVar[int]
    mesh: str
    options: RefineOptions
    cameras: int
    vertex_buffer_hash: str
    resume_token: str
    last_frame_seq: int
    ack_window: int
    client: str
    cache_vertices: int
    cache_strategy: CacheStrategy
    cache_pq_fraction: float
    frame_encoding: FrameEncoding
    vertex_encoding: VertexEncoding
    position_bits: int
    morph_targets: bool
    def __init__(self, mesh: _Optional[str] = ..., options: _Optional[_Union[RefineOptions, _Mapping]] = ..., cameras: _Optional[int] = ..., vertex_buffer_hash: _Optional[str] = ..., resume_token: _Optional[str] = ..., last_frame_seq: _Optional[int] = ..., ack_window: _Optional[int] = ..., client: _Optional[str] = ..., cache_vertices: _Optional[int] = ..., cache_strategy: _Optional[_Union[CacheStrategy, str]] = ..., cache_pq_fraction: _Optional[float] = ..., frame_encoding: _Optional[_Union[FrameEncoding, str]] = ..., vertex_encoding: _Optional[_Union[VertexEncoding, str]] = ..., position_bits: _Optional[int] = ..., morph_targets: _Optional[bool] = ...) -> None: ...

class RefineOptions(_message.Message):
    __slots__ = ("viewport_width", "viewport_height", "fov_y_deg", "tolerance_px", "cull", "backface", "max_ops", "max_faces", "prune", "strict_bound")
    VIEWPORT_WIDTH_FIELD_NUMBER: _ClassVar[int]
    VIEWPORT_HEIGHT_FIELD_NUMBER: _ClassVar[int]
    FOV_Y_DEG_FIELD_NUMBER: _ClassVar[int]
    TOLERANCE_PX_FIELD_NUMBER: _ClassVar[int]
    CULL_FIELD_NUMBER: _ClassVar[int]
    BACKFACE_FIELD_NUMBER: _ClassVar[int]
    MAX_OPS_FIELD_NUMBER: _ClassVar[int]
    MAX_FACES_FIELD_NUMBER: _ClassVar[int]
    PRUNE_FIELD_NUMBER: _ClassVar[int]
    STRICT_BOUND_FIELD_NUMBER: _ClassVar[int]
    viewport_width: int
    viewport_height: int
    fov_y_deg: float
    tolerance_px: float
    cull: bool
    backface: bool
    max_ops: int
    max_faces: int
    prune: bool
    strict_bound: bool
    def __init__(self, viewport_width: _Optional[int] = ..., viewport_height: _Optional[int] = ..., fov_y_deg: _Optional[float] = ..., tolerance_px: _Optional[float] = ..., cull: _Optional[bool] = ..., backface: _Optional[bool] = ..., max_ops: _Optional[int] = ..., max_faces: _Optional[int] = ..., prune: _Optional[bool] = ..., strict_bound: _Optional[bool] = ...) -> None: ...

class CameraPose(_message.Message):
    __slots__ = ("camera", "pose_seq", "eye", "target", "up", "ack_frame_seq")
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    POSE_SEQ_FIELD_NUMBER: _ClassVar[int]
    EYE_FIELD_NUMBER: _ClassVar[int]
    TARGET_FIELD_NUMBER: _ClassVar[int]
    UP_FIELD_NUMBER: _ClassVar[int]
    ACK_FRAME_SEQ_FIELD_NUMBER: _ClassVar[int]
    camera: int
    pose_seq: int
    eye: Vec3
    target: Vec3
    up: Vec3
    ack_frame_seq: int
    def __init__(self, camera: _Optional[int] = ..., pose_seq: _Optional[int] = ..., eye: _Optional[_Union[Vec3, _Mapping]] = ..., target: _Optional[_Union[Vec3, _Mapping]] = ..., up: _Optional[_Union[Vec3, _Mapping]] = ..., ack_frame_seq: _Optional[int] = ...) -> None: ...

class Ack(_message.Message):
    __slots__ = ("frame_seq",)
    FRAME_SEQ_FIELD_NUMBER: _ClassVar[int]
    frame_seq: int
    def __init__(self, frame_seq: _Optional[int] = ...) -> None: ...

class KeyframeRequest(_message.Message):
    __slots__ = ("camera", "reason", "frame_seq", "detail")
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    FRAME_SEQ_FIELD_NUMBER: _ClassVar[int]
    DETAIL_FIELD_NUMBER: _ClassVar[int]
    camera: int
    reason: KeyframeReason
    frame_seq: int
    detail: str
    def __init__(self, camera: _Optional[int] = ..., reason: _Optional[_Union[KeyframeReason, str]] = ..., frame_seq: _Optional[int] = ..., detail: _Optional[str] = ...) -> None: ...

class Close(_message.Message):
    __slots__ = ("reason",)
    REASON_FIELD_NUMBER: _ClassVar[int]
    reason: str
    def __init__(self, reason: _Optional[str] = ...) -> None: ...

class ServerMessage(_message.Message):
    __slots__ = ("session_info", "vertex_chunk", "frame", "status")
    SESSION_INFO_FIELD_NUMBER: _ClassVar[int]
    VERTEX_CHUNK_FIELD_NUMBER: _ClassVar[int]
    FRAME_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    session_info: SessionInfo
    vertex_chunk: VertexChunk
    frame: Frame
    status: Status
    def __init__(self, session_info: _Optional[_Union[SessionInfo, _Mapping]] = ..., vertex_chunk: _Optional[_Union[VertexChunk, _Mapping]] = ..., frame: _Optional[_Union[Frame, _Mapping]] = ..., status: _Optional[_Union[Status, _Mapping]] = ...) -> None: ...

class Status(_message.Message):
    __slots__ = ("code", "message")
    CODE_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    code: int
    message: str
    def __init__(self, code: _Optional[int] = ..., message: _Optional[str] = ...) -> None: ...

class SessionInfo(_message.Message):
    __slots__ = ("session_token", "resumed", "mesh", "vertex_format", "vertex_buffer_cached", "vertex_payload_crc32", "options", "cameras", "ack_window", "resume_ttl_s", "last_frame_seq", "last_pose_seq", "max_chunk_bytes", "cache_vertices", "cache_strategy", "cache_pq_fraction", "frame_encoding", "acks_on_poses", "vertex_packing")
    SESSION_TOKEN_FIELD_NUMBER: _ClassVar[int]
    RESUMED_FIELD_NUMBER: _ClassVar[int]
    MESH_FIELD_NUMBER: _ClassVar[int]
    VERTEX_FORMAT_FIELD_NUMBER: _ClassVar[int]
    VERTEX_BUFFER_CACHED_FIELD_NUMBER: _ClassVar[int]
    VERTEX_PAYLOAD_CRC32_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    CAMERAS_FIELD_NUMBER: _ClassVar[int]
    ACK_WINDOW_FIELD_NUMBER: _ClassVar[int]
    RESUME_TTL_S_FIELD_NUMBER: _ClassVar[int]
    LAST_FRAME_SEQ_FIELD_NUMBER: _ClassVar[int]
    LAST_POSE_SEQ_FIELD_NUMBER: _ClassVar[int]
    MAX_CHUNK_BYTES_FIELD_NUMBER: _ClassVar[int]
    CACHE_VERTICES_FIELD_NUMBER: _ClassVar[int]
    CACHE_STRATEGY_FIELD_NUMBER: _ClassVar[int]
    CACHE_PQ_FRACTION_FIELD_NUMBER: _ClassVar[int]
    FRAME_ENCODING_FIELD_NUMBER: _ClassVar[int]
    ACKS_ON_POSES_FIELD_NUMBER: _ClassVar[int]
    VERTEX_PACKING_FIELD_NUMBER: _ClassVar[int]
    session_token: str
    resumed: bool
    mesh: MeshInfo
    vertex_format: VertexFormat
    vertex_buffer_cached: bool
    vertex_payload_crc32: int
    options: RefineOptions
    cameras: int
    ack_window: int
    resume_ttl_s: int
    last_frame_seq: int
    last_pose_seq: int
    max_chunk_bytes: int
    cache_vertices: int
    cache_strategy: CacheStrategy
    cache_pq_fraction: float
    frame_encoding: FrameEncoding
    acks_on_poses: bool
    vertex_packing: VertexPacking
    def __init__(self, session_token: _Optional[str] = ..., resumed: _Optional[bool] = ..., mesh: _Optional[_Union[MeshInfo, _Mapping]] = ..., vertex_format: _Optional[_Union[VertexFormat, _Mapping]] = ..., vertex_buffer_cached: _Optional[bool] = ..., vertex_payload_crc32: _Optional[int] = ..., options: _Optional[_Union[RefineOptions, _Mapping]] = ..., cameras: _Optional[int] = ..., ack_window: _Optional[int] = ..., resume_ttl_s: _Optional[int] = ..., last_frame_seq: _Optional[int] = ..., last_pose_seq: _Optional[int] = ..., max_chunk_bytes: _Optional[int] = ..., cache_vertices: _Optional[int] = ..., cache_strategy: _Optional[_Union[CacheStrategy, str]] = ..., cache_pq_fraction: _Optional[float] = ..., frame_encoding: _Optional[_Union[FrameEncoding, str]] = ..., acks_on_poses: _Optional[bool] = ..., vertex_packing: _Optional[_Union[VertexPacking, _Mapping]] = ...) -> None: ...

class VertexPacking(_message.Message):
    __slots__ = ("encoding", "packed_bytes", "packed_crc32", "vertex_buffer_hash", "position_bits", "position_origin", "position_step", "normal_bits", "texcoord_step", "max_position_error", "max_normal_degrees")
    ENCODING_FIELD_NUMBER: _ClassVar[int]
    PACKED_BYTES_FIELD_NUMBER: _ClassVar[int]
    PACKED_CRC32_FIELD_NUMBER: _ClassVar[int]
    VERTEX_BUFFER_HASH_FIELD_NUMBER: _ClassVar[int]
    POSITION_BITS_FIELD_NUMBER: _ClassVar[int]
    POSITION_ORIGIN_FIELD_NUMBER: _ClassVar[int]
    POSITION_STEP_FIELD_NUMBER: _ClassVar[int]
    NORMAL_BITS_FIELD_NUMBER: _ClassVar[int]
    TEXCOORD_STEP_FIELD_NUMBER: _ClassVar[int]
    MAX_POSITION_ERROR_FIELD_NUMBER: _ClassVar[int]
    MAX_NORMAL_DEGREES_FIELD_NUMBER: _ClassVar[int]
    encoding: VertexEncoding
    packed_bytes: int
    packed_crc32: int
    vertex_buffer_hash: str
    position_bits: int
    position_origin: Vec3
    position_step: float
    normal_bits: int
    texcoord_step: float
    max_position_error: float
    max_normal_degrees: float
    def __init__(self, encoding: _Optional[_Union[VertexEncoding, str]] = ..., packed_bytes: _Optional[int] = ..., packed_crc32: _Optional[int] = ..., vertex_buffer_hash: _Optional[str] = ..., position_bits: _Optional[int] = ..., position_origin: _Optional[_Union[Vec3, _Mapping]] = ..., position_step: _Optional[float] = ..., normal_bits: _Optional[int] = ..., texcoord_step: _Optional[float] = ..., max_position_error: _Optional[float] = ..., max_normal_degrees: _Optional[float] = ...) -> None: ...

class MeshInfo(_message.Message):
    __slots__ = ("name", "faces", "vertices", "positions", "nodes", "base_faces", "surface_group_ids", "materials", "bounds_min", "bounds_max", "content_hash", "vertex_buffer_hash", "origin")
    NAME_FIELD_NUMBER: _ClassVar[int]
    FACES_FIELD_NUMBER: _ClassVar[int]
    VERTICES_FIELD_NUMBER: _ClassVar[int]
    POSITIONS_FIELD_NUMBER: _ClassVar[int]
    NODES_FIELD_NUMBER: _ClassVar[int]
    BASE_FACES_FIELD_NUMBER: _ClassVar[int]
    SURFACE_GROUP_IDS_FIELD_NUMBER: _ClassVar[int]
    MATERIALS_FIELD_NUMBER: _ClassVar[int]
    BOUNDS_MIN_FIELD_NUMBER: _ClassVar[int]
    BOUNDS_MAX_FIELD_NUMBER: _ClassVar[int]
    CONTENT_HASH_FIELD_NUMBER: _ClassVar[int]
    VERTEX_BUFFER_HASH_FIELD_NUMBER: _ClassVar[int]
    ORIGIN_FIELD_NUMBER: _ClassVar[int]
    name: str
    faces: int
    vertices: int
    positions: int
    nodes: int
    base_faces: int
    surface_group_ids: int
    materials: _containers.RepeatedCompositeFieldContainer[Material]
    bounds_min: Vec3
    bounds_max: Vec3
    content_hash: str
    vertex_buffer_hash: str
    origin: Vec3
    def __init__(self, name: _Optional[str] = ..., faces: _Optional[int] = ..., vertices: _Optional[int] = ..., positions: _Optional[int] = ..., nodes: _Optional[int] = ..., base_faces: _Optional[int] = ..., surface_group_ids: _Optional[int] = ..., materials: _Optional[_Iterable[_Union[Material, _Mapping]]] = ..., bounds_min: _Optional[_Union[Vec3, _Mapping]] = ..., bounds_max: _Optional[_Union[Vec3, _Mapping]] = ..., content_hash: _Optional[str] = ..., vertex_buffer_hash: _Optional[str] = ..., origin: _Optional[_Union[Vec3, _Mapping]] = ...) -> None: ...

class Material(_message.Message):
    __slots__ = ("id", "name")
    ID_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    id: int
    name: str
    def __init__(self, id: _Optional[int] = ..., name: _Optional[str] = ...) -> None: ...

class VertexFormat(_message.Message):
    __slots__ = ("layout", "vertex_count", "payload_bytes", "attributes")
    LAYOUT_FIELD_NUMBER: _ClassVar[int]
    VERTEX_COUNT_FIELD_NUMBER: _ClassVar[int]
    PAYLOAD_BYTES_FIELD_NUMBER: _ClassVar[int]
    ATTRIBUTES_FIELD_NUMBER: _ClassVar[int]
    layout: VertexLayout
    vertex_count: int
    payload_bytes: int
    attributes: _containers.RepeatedCompositeFieldContainer[VertexAttribute]
    def __init__(self, layout: _Optional[_Union[VertexLayout, str]] = ..., vertex_count: _Optional[int] = ..., payload_bytes: _Optional[int] = ..., attributes: _Optional[_Iterable[_Union[VertexAttribute, _Mapping]]] = ...) -> None: ...

class VertexAttribute(_message.Message):
    __slots__ = ("semantic", "type", "components", "normalized", "offset", "stride")
    SEMANTIC_FIELD_NUMBER: _ClassVar[int]
    TYPE_FIELD_NUMBER: _ClassVar[int]
    COMPONENTS_FIELD_NUMBER: _ClassVar[int]
    NORMALIZED_FIELD_NUMBER: _ClassVar[int]
    OFFSET_FIELD_NUMBER: _ClassVar[int]
    STRIDE_FIELD_NUMBER: _ClassVar[int]
    semantic: AttributeSemantic
    type: ScalarType
    components: int
    normalized: bool
    offset: int
    stride: int
    def __init__(self, semantic: _Optional[_Union[AttributeSemantic, str]] = ..., type: _Optional[_Union[ScalarType, str]] = ..., components: _Optional[int] = ..., normalized: _Optional[bool] = ..., offset: _Optional[int] = ..., stride: _Optional[int] = ...) -> None: ...

class VertexChunk(_message.Message):
    __slots__ = ("offset", "total", "data")
    OFFSET_FIELD_NUMBER: _ClassVar[int]
    TOTAL_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    offset: int
    total: int
    data: bytes
    def __init__(self, offset: _Optional[int] = ..., total: _Optional[int] = ..., data: _Optional[bytes] = ...) -> None: ...

class Frame(_message.Message):
    __slots__ = ("frame_seq", "pose_seq", "cameras", "continued", "poses_superseded")
    FRAME_SEQ_FIELD_NUMBER: _ClassVar[int]
    POSE_SEQ_FIELD_NUMBER: _ClassVar[int]
    CAMERAS_FIELD_NUMBER: _ClassVar[int]
    CONTINUED_FIELD_NUMBER: _ClassVar[int]
    POSES_SUPERSEDED_FIELD_NUMBER: _ClassVar[int]
    frame_seq: int
    pose_seq: int
    cameras: _containers.RepeatedCompositeFieldContainer[CameraFrame]
    continued: bool
    poses_superseded: int
    def __init__(self, frame_seq: _Optional[int] = ..., pose_seq: _Optional[int] = ..., cameras: _Optional[_Iterable[_Union[CameraFrame, _Mapping]]] = ..., continued: _Optional[bool] = ..., poses_superseded: _Optional[int] = ...) -> None: ...

class CameraFrame(_message.Message):
    __slots__ = ("camera", "pose_seq", "keyframe", "surfaces", "stats", "vertices")
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    POSE_SEQ_FIELD_NUMBER: _ClassVar[int]
    KEYFRAME_FIELD_NUMBER: _ClassVar[int]
    SURFACES_FIELD_NUMBER: _ClassVar[int]
    STATS_FIELD_NUMBER: _ClassVar[int]
    VERTICES_FIELD_NUMBER: _ClassVar[int]
    camera: int
    pose_seq: int
    keyframe: bool
    surfaces: _containers.RepeatedCompositeFieldContainer[SurfaceDelta]
    stats: CameraStats
    vertices: VertexWrites
    def __init__(self, camera: _Optional[int] = ..., pose_seq: _Optional[int] = ..., keyframe: _Optional[bool] = ..., surfaces: _Optional[_Iterable[_Union[SurfaceDelta, _Mapping]]] = ..., stats: _Optional[_Union[CameraStats, _Mapping]] = ..., vertices: _Optional[_Union[VertexWrites, _Mapping]] = ...) -> None: ...

class VertexWrites(_message.Message):
    __slots__ = ("slots", "first_slot", "data", "slots_checksum")
    SLOTS_FIELD_NUMBER: _ClassVar[int]
    FIRST_SLOT_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    SLOTS_CHECKSUM_FIELD_NUMBER: _ClassVar[int]
    slots: bytes
    first_slot: int
    data: bytes
    slots_checksum: int
    def __init__(self, slots: _Optional[bytes] = ..., first_slot: _Optional[int] = ..., data: _Optional[bytes] = ..., slots_checksum: _Optional[int] = ...) -> None: ...

class SurfaceDelta(_message.Message):
    __slots__ = ("material", "count", "slots", "first_slot", "tris", "crc32", "ops")
    MATERIAL_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    SLOTS_FIELD_NUMBER: _ClassVar[int]
    FIRST_SLOT_FIELD_NUMBER: _ClassVar[int]
    TRIS_FIELD_NUMBER: _ClassVar[int]
    CRC32_FIELD_NUMBER: _ClassVar[int]
    OPS_FIELD_NUMBER: _ClassVar[int]
    material: int
    count: int
    slots: bytes
    first_slot: int
    tris: bytes
    crc32: int
    ops: bytes
    def __init__(self, material: _Optional[int] = ..., count: _Optional[int] = ..., slots: _Optional[bytes] = ..., first_slot: _Optional[int] = ..., tris: _Optional[bytes] = ..., crc32: _Optional[int] = ..., ops: _Optional[bytes] = ...) -> None: ...

class CameraStats(_message.Message):
    __slots__ = ("splits", "collapses", "update_us", "active_faces", "budget_exhausted", "pose_age_us", "cache_hits", "cache_inserts", "cache_tolerance_px", "updates", "hidden_parts")
    SPLITS_FIELD_NUMBER: _ClassVar[int]
    COLLAPSES_FIELD_NUMBER: _ClassVar[int]
    UPDATE_US_FIELD_NUMBER: _ClassVar[int]
    ACTIVE_FACES_FIELD_NUMBER: _ClassVar[int]
    BUDGET_EXHAUSTED_FIELD_NUMBER: _ClassVar[int]
    POSE_AGE_US_FIELD_NUMBER: _ClassVar[int]
    CACHE_HITS_FIELD_NUMBER: _ClassVar[int]
    CACHE_INSERTS_FIELD_NUMBER: _ClassVar[int]
    CACHE_TOLERANCE_PX_FIELD_NUMBER: _ClassVar[int]
    UPDATES_FIELD_NUMBER: _ClassVar[int]
    HIDDEN_PARTS_FIELD_NUMBER: _ClassVar[int]
    splits: int
    collapses: int
    update_us: int
    active_faces: int
    budget_exhausted: bool
    pose_age_us: int
    cache_hits: int
    cache_inserts: int
    cache_tolerance_px: float
    updates: int
    hidden_parts: int
    def __init__(self, splits: _Optional[int] = ..., collapses: _Optional[int] = ..., update_us: _Optional[int] = ..., active_faces: _Optional[int] = ..., budget_exhausted: _Optional[bool] = ..., pose_age_us: _Optional[int] = ..., cache_hits: _Optional[int] = ..., cache_inserts: _Optional[int] = ..., cache_tolerance_px: _Optional[float] = ..., updates: _Optional[int] = ..., hidden_parts: _Optional[int] = ...) -> None: ...

class Vec3(_message.Message):
    __slots__ = ("x", "y", "z")
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    x: float
    y: float
    z: float
    def __init__(self, x: _Optional[float] = ..., y: _Optional[float] = ..., z: _Optional[float] = ...) -> None: ...

class ListMeshesRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ListMeshesResponse(_message.Message):
    __slots__ = ("meshes",)
    MESHES_FIELD_NUMBER: _ClassVar[int]
    meshes: _containers.RepeatedCompositeFieldContainer[MeshInfo]
    def __init__(self, meshes: _Optional[_Iterable[_Union[MeshInfo, _Mapping]]] = ...) -> None: ...
