#!/usr/bin/env python3
"""Writes the seed corpora in tests/fuzz/corpus/<target>/ (checked in).

Run from anywhere: python3 tests/fuzz/make_seeds.py. Rewrites the seed_*
files it makes and leaves every other file (inputs added by scripts/fuzz
--merge, hand-made ones) alone. The binary seeds of dds_convert, grbl and
commands follow the byte layouts their fuzz_<name>.cc decode.
"""
import os
import struct

ROOT = os.path.dirname(os.path.abspath(__file__))
CORPUS = os.path.join(ROOT, "corpus")


def put(target, name, data):
    folder = os.path.join(CORPUS, target)
    os.makedirs(folder, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(folder, "seed_" + name), "wb") as f:
        f.write(data)


# --- PLY ------------------------------------------------------------------
def ply_header(fmt, elements, crlf=False, extra=""):
    lines = ["ply", "format %s 1.0" % fmt, "comment craftscan seed", "obj_info seed"]
    for name, count, props in elements:
        lines.append("element %s %d" % (name, count))
        lines += ["property " + p for p in props]
    lines.append("end_header")
    sep = "\r\n" if crlf else "\n"
    return (sep.join(lines) + sep + extra).encode()


XYZ = ["float x", "float y", "float z"]
pts = [(0.0, 1.5, -2.25), (10.0, 20.0, 30.0), (-1e3, 3.4e38, 1e-40)]
put("ply", "ascii_xyz.ply",
    ply_header("ascii", [("vertex", 3, XYZ)]) +
    b"".join(b"%r %r %r\n" % p for p in pts))
put("ply", "ascii_normals_colors.ply",
    ply_header("ascii", [("vertex", 2, XYZ + ["float nx", "float ny", "float nz",
                                                "uchar red", "uchar green", "uchar blue"])]) +
    b"1 2 3 0 0 1 255 128 0\n4 5 6 0.6 0.8 0 12 34 56\n")
put("ply", "binary_le_rgb.ply",
    ply_header("binary_little_endian", [("vertex", 2, XYZ + ["uchar red", "uchar green",
                                                            "uchar blue"])]) +
    struct.pack("<3f3B", 1, 2, 3, 10, 20, 30) + struct.pack("<3f3B", -1, -2, -3, 40, 50, 60))
put("ply", "binary_be_double.ply",
    ply_header("binary_big_endian", [("vertex", 2, ["double x", "double y", "double z"])]) +
    struct.pack(">3d", 0.001, 0.002, 0.003) + struct.pack(">3d", 1, 2, 3))
put("ply", "ascii_faces_after.ply",
    ply_header("ascii", [("vertex", 3, XYZ),
                         ("face", 1, ["list uchar int vertex_indices"])]) +
    b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
put("ply", "binary_faces_before.ply",
    ply_header("binary_little_endian", [("face", 1, ["list uchar uint vertex_indices"]),
                                        ("vertex", 1, XYZ)]) +
    struct.pack("<B3I", 3, 0, 1, 2) + struct.pack("<3f", 7, 8, 9))
put("ply", "crlf_header.ply",
    ply_header("ascii", [("vertex", 1, XYZ)], crlf=True) + b"1 2 3\r\n")
put("ply", "float_colors.ply",
    ply_header("ascii", [("vertex", 1, XYZ + ["float red", "float green", "float blue"])]) +
    b"1 2 3 0.5 1.5 -0.5\n")
put("ply", "diffuse_colors.ply",
    ply_header("ascii", [("vertex", 1, XYZ + ["uchar diffuse_red", "uchar diffuse_green",
                                              "uchar diffuse_blue"])]) + b"1 2 3 4 5 6\n")
put("ply", "all_int_types.ply",
    ply_header("binary_little_endian",
               [("vertex", 1, ["char x", "short y", "int z", "uchar a", "ushort b", "uint c",
                               "int8 d", "uint8 e", "int16 f", "uint16 g", "int32 h",
                               "uint32 i", "float32 j", "float64 k"])]) +
    struct.pack("<bhiBHIbBhHiIfd", -1, -2, -3, 1, 2, 3, 4, 5, 6, 7, 8, 9, 1.5, 2.5))
put("ply", "empty.ply", ply_header("ascii", [("vertex", 0, XYZ)]))
put("ply", "truncated.ply",
    ply_header("binary_little_endian", [("vertex", 4, XYZ)]) + struct.pack("<4f", 1, 2, 3, 4))
put("ply", "huge_count.ply", ply_header("ascii", [("vertex", 10**12, XYZ)]) + b"1 2 3\n")
put("ply", "range_grid.ply",
    ply_header("ascii", [("vertex", 1, XYZ + ["int flags"]),
                         ("range_grid", 2, ["list uchar int vertex_indices"])]) +
    b"1 2 3 7\n1 0\n0\n")

# --- PFM ------------------------------------------------------------------
put("pfm", "gray_le.pfm", b"Pf\n2 2\n-1.0\n" + struct.pack("<4f", 0, 1.5, float("nan"), -3))
put("pfm", "gray_be.pfm", b"Pf\n3 1\n1.0\n" + struct.pack(">3f", 1, 2, 3))
put("pfm", "color_le.pfm", b"PF\n1 2\n-1\n" + struct.pack("<6f", 1, 2, 3, 4, 5, 6))
put("pfm", "spaces.pfm", b"Pf  1\t1 \n -0.5\n" + struct.pack("<f", 42))
put("pfm", "truncated.pfm", b"Pf\n4 4\n-1.0\n" + struct.pack("<3f", 1, 2, 3))
put("pfm", "bad_scale.pfm", b"Pf\n1 1\nnan\n" + struct.pack("<f", 1))

# --- Calibration (OpenCV YAML, as SaveCalibration writes it) ---------------
def matrix(rows, cols, values, indent="   "):
    data = ", ".join(repr(float(v)) for v in values)
    return ("!!opencv-matrix\n%srows: %d\n%scols: %d\n%sdt: d\n%sdata: [ %s ]"
            % (indent, rows, indent, cols, indent, indent, data))


def calibration(distortion=5, board="chessboard", report=True, valid=1):
    f, cx, cy, b = 800.0, 320.0, 240.0, 100.0
    k = [f, 0, cx, 0, f, cy, 0, 0, 1]
    eye = [1, 0, 0, 0, 1, 0, 0, 0, 1]
    d = [0.01, -0.02, 0.001, 0.0005, 0.003] + ([0.1, 0.01, 0.001] if distortion == 8 else [])
    p1 = [f, 0, cx, 0, 0, f, cy, 0, 0, 0, 1, 0]
    p2 = [f, 0, cx, -f * b, 0, f, cy, 0, 0, 0, 1, 0]
    q = [1, 0, 0, -cx, 0, 1, 0, -cy, 0, 0, 0, f, 0, 0, 1 / b, 0]
    text = "%YAML:1.0\n---\n"
    text += "format: craftscan-stereo-calibration\nformat_version: 1\n"
    text += "image_width: 640\nimage_height: 480\n"
    text += "board:\n   type: %s\n   cols: 9\n   rows: 6\n" % board
    text += "   square_mm: 8.\n   marker_mm: %s\n   aruco_dictionary: 0\n" % (
        "6." if board == "charuco" else "0.")
    for side in ("left", "right"):
        text += "%s:\n   camera_matrix: %s\n   distortion: %s\n" % (
            side, matrix(3, 3, k, "      "), matrix(1, distortion, d, "      "))
    text += "R: %s\n" % matrix(3, 3, eye)
    text += "T: %s\n" % matrix(3, 1, [-b, 0, 0])
    text += "R1: %s\nR2: %s\n" % (matrix(3, 3, eye), matrix(3, 3, eye))
    text += "P1: %s\nP2: %s\n" % (matrix(3, 4, p1), matrix(3, 4, p2))
    text += "Q: %s\n" % matrix(4, 4, q)
    text += "turntable:\n   valid: %d\n   direction_in_rig: %s\n   point_in_rig_mm: %s\n" % (
        valid, matrix(3, 1, [0, -1, 0], "      "), matrix(3, 1, [0, 50, 400], "      "))
    if report:
        text += ("report:\n   rms_left_px: 0.21\n   rms_right_px: 0.23\n   rms_stereo_px: 0.3\n"
                 "   epipolar_mean_px: 0.1\n   epipolar_max_px: 0.4\n   coverage_grid: 4\n"
                 "   coverage_left: 0.8\n   coverage_right: 0.75\n   views_used: 2\n"
                 "   verdict: accept\n   verdict_reason: \"\"\n   turntable_steps: 8\n"
                 "   turntable_residual_mm: 0.05\n   turntable_max_angle_error_deg: 0.02\n"
                 "   views:\n"
                 "      - { name: view_000, used: 1, message: \"\", num_points: 54,"
                 " rms_left_px: 0.2, rms_right_px: 0.2, rms_stereo_px: 0.3 }\n"
                 "      - { name: view_001, used: 0, message: \"board not found\","
                 " num_points: 0, rms_left_px: .Nan, rms_right_px: .Nan,"
                 " rms_stereo_px: .Nan }\n")
    return text


put("calibration", "plumb_bob.yaml", calibration())
put("calibration", "rational.yaml", calibration(distortion=8, report=False))
put("calibration", "charuco.yaml", calibration(board="charuco", valid=0))
put("calibration", "wrong_version.yaml",
    calibration().replace("format_version: 1", "format_version: 2"))
put("calibration", "not_a_map.yaml", "%YAML:1.0\n---\n- 1\n- 2\n")
put("calibration", "json.yaml", '{"format": "craftscan-stereo-calibration", "format_version": 1}')

# --- Daemon config (the example file, the dump's shape, overrides) --------
with open(os.path.join(ROOT, "..", "..", "systemd", "craftscand.yaml"), "rb") as f:
    put("config", "example.yaml", f.read())
put("config", "minimal.yaml", "version: 1\n")
put("config", "env_overrides.yaml",
    b"version: 1\nstation: bench_2\nscan: {views: 8, step_deg: 45}\n\0"
    b"CRAFTSCAN_SCAN_VIEWS=12\nCRAFTSCAN_SCAN_STEP_DEG=30\n"
    b"CRAFTSCAN_PLUGINS_PATH=/usr/lib/a:/opt/b\nCRAFTSCAN_WATCHDOG_ENABLED=off\n"
    b"CRAFTSCAN_LOG_LEVEL=debug\nCRAFTSCAN_TOKEN=ignored\n")
put("config", "full.yaml", """version: 1
station: station1
data_dir: "/var/lib/craftscan"
log_level: warning
dds: {domain: 7, config_file: ""}
auth: {tokens_file: "/etc/craftscan/tokens.yaml"}
plugins: {path: ["/usr/lib/craftscan/drivers", "/opt/craftscan/drivers"]}
devices:
  camera: {driver: aravis, config: {left: "192.168.10.11", right: "192.168.10.12"}}
  turntable: {driver: serial_turntable, config: {port: /dev/ttyUSB0, baud: 115200}}
calibration:
  board: {type: charuco, cols: 11, rows: 8, square_mm: 15, marker_mm: 11, dictionary: DICT_5X5_100}
  turntable_board: {type: chessboard, cols: 7, rows: 4, square_mm: 12}
  turntable_board_thickness_mm: 3
  views: 20
  max_rms_px: 0.4
scan: {views: 24, step_deg: 15, settle_ms: 300, exposure_us: 8000, gain_db: 2.5}
pipeline:
  threads: 4
  min_disparity: -16
  num_disparities: 128
  min_texture_std: 0
  volume_radius_mm: 150
  volume_min_height_mm: 1
  volume_max_height_mm: 250
  mesh: no
limits: {max_command_bytes: 1024, queue_capacity: 16}
watchdog: {enabled: false}
""")
put("config", "bad_key.yaml", "version: 1\nscan: {veiws: 3}\n")
put("config", "bad_version.yaml", "version: 2\n")

# --- Tokens file ------------------------------------------------------------
put("auth", "tokens.yaml", """tokens:
  - {name: console, token: "k3J9xQ2mV8pL5nR7tY1wZ4", role: operator}
  - {name: archive, token: "archive-token-0000000000", role: observer}
  - name: admin@site
    token: adm1n.t0ken-with_symbols!#
    role: admin
#k3J9xQ2mV8pL5nR7tY1wZ4""")
put("auth", "empty_list.yaml", "tokens: []\n")
put("auth", "observer_asks.yaml", """tokens:
  - {name: archive, token: "archive-token-0000000000", role: observer}
#archive-token-0000000000""")
put("auth", "duplicate.yaml", """tokens:
  - {name: a, token: "aaaaaaaaaaaaaaaa", role: admin}
  - {name: b, token: "aaaaaaaaaaaaaaaa", role: admin}
""")
put("auth", "bad_role.yaml", "tokens:\n  - {name: a, token: \"bbbbbbbbbbbbbbbb\", role: root}\n")
put("auth", "unknown_key.yaml", "tokens: []\nextra: 1\n")

# --- GRBL replies: [max line - 1][chunk - 1] then the bytes from the port ---
grbl = (b"\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\nok\r\n"
        b"<Idle|MPos:12.000,0.000,0.000|FS:0,0>\r\n<Run|WPos:1.500,0,0|WCO:3.000,0,0|FS:500,0>\n"
        b"<Hold:0|MPos:-90.125,0,0>\r\nerror:20\r\nALARM:1\r\nerror:99\r\n[GC:G0 G54 G17]\r\n"
        b"<Alarm|MPos:nan,0,0>\r\n\xff\xfeok\r\n<Home|Bf:15,128|MPos:0,0,0>\r\n")
put("grbl", "transcript", bytes([255, 63]) + grbl)
put("grbl", "small_chunks", bytes([40, 0]) + grbl)
put("grbl", "overlong", bytes([15, 7]) + b"[MSG:" + b"x" * 100 + b"]\r\nok\r\n")

# --- Commands: [token 0..4][request id]\n[client]\n[verb]\n[arguments JSON] --
def command(token, verb, arguments="", request="req-1", client="console"):
    return bytes([token]) + ("%s\n%s\n%s\n%s" % (request, client, verb, arguments)).encode()


put("commands", "status", command(0, "status"))
put("commands", "scan", command(1, "scan", '{"object": "carved egg", "views": 24, "step_deg": 15.0}'))
put("commands", "capture", command(1, "capture", '{"object": "egg"}'))
put("commands", "get", command(0, "get", '{"session": "20240501-093000-egg"}'))
put("commands", "get_files", command(0, "get", '{"session": "20240501-093000-egg-2", '
                                     '"files": ["fused.ply", "previews/a.png"], "chunk_bytes": 65536}'))
put("commands", "get_all", command(0, "get", '{"session": "20240501-093000-egg", "files": "all"}'))
put("commands", "resume", command(1, "resume", '{"session": "20240501-093000-egg"}'))
put("commands", "turntable_move", command(1, "turntable", '{"action": "move", "angle_deg": -45.5}'))
put("commands", "turntable_home", command(2, "turntable", '{"action": "home"}'))
put("commands", "camera", command(1, "camera", '{"exposure_us": 8000, "gain_db": 3}'))
put("commands", "calibrate", command(2, "calibrate-turntable", "{}"))
put("commands", "forbidden", command(0, "calibrate"))
put("commands", "unknown_token", command(3, "status"))
put("commands", "bad_json", command(1, "scan", '{"views": 24,'))
put("commands", "bad_argument", command(1, "scan", '{"views": 2.5, "extra": null}'))
put("commands", "traversal", command(0, "get", '{"session": "../../etc/passwd"}'))

# --- Session manifests ------------------------------------------------------
manifest = """{"format": "craftscan-session", "format_version": 1,
 "id": "20240501-093000-egg", "object": {"name": "carved egg", "sanitized": "carved_egg"},
 "job": "scan", "params": {"views": 24, "step_deg": 15.0, "client": "console"},
 "state": "capturing", "error": "",
 "created": "2024-05-01T09:30:00.000Z", "updated": "2024-05-01T09:30:07.412Z",
 "calibration": {"id": "rig-a", "file": "calibration.yaml", "size": 2210,
                 "fnv1a64": "9ae16a3b2f90404f"},
 "views": [{"index": 0, "angle_deg": 0.0, "captured": "2024-05-01T09:30:03.101Z",
            "files": {"left.png": {"size": 812345, "fnv1a64": "0123456789abcdef"},
                      "right.png": {"size": 811111, "fnv1a64": "fedcba9876543210"},
                      "meta.json": {"size": 310, "fnv1a64": "00000000deadbeef"},
                      "disparity.pfm": {"size": 1228817, "fnv1a64": "1111111111111111"},
                      "cloud.ply": {"size": 99999, "fnv1a64": "2222222222222222"}}},
           {"index": 1, "angle_deg": 15, "captured": "2024-05-01T09:30:05.000Z",
            "files": {"left.png": {"size": 1, "fnv1a64": "3333333333333333"}}}],
 "outputs": {"fused.ply": {"size": 5, "fnv1a64": "4444444444444444"},
             "previews/view_000.png": {"size": 6, "fnv1a64": "5555555555555555"}},
 "journal": [{"time": "2024-05-01T09:30:00.000Z", "event": "created", "detail": "scan of 'egg'"},
             {"time": "2024-05-01T09:30:01.000Z", "event": "capturing", "detail": ""}]}
"""
put("manifest", "capturing.json", manifest)
put("manifest", "done_no_calibration.json",
    manifest.replace('"state": "capturing"', '"state": "done"')
    .replace('"calibration": {"id": "rig-a", "file": "calibration.yaml", "size": 2210,\n'
             '                 "fnv1a64": "9ae16a3b2f90404f"}', '"calibration": null'))
put("manifest", "bad_view_file.json", manifest.replace('"cloud.ply"', '"../cloud.ply"'))
put("manifest", "duplicate_view.json", manifest.replace('"index": 1', '"index": 0'))
put("manifest", "bad_output.json", manifest.replace('"fused.ply"', '"views/x.ply"'))


# --- DDS messages: [reader 0..4][flags] then the fields fuzz_dds_convert.cc reads --
def le32(*values):
    return struct.pack("<%dI" % len(values), *values)


def field(name_index, offset, datatype, count=1):
    # name: 1 + index into the known names; offset: Small(63); datatype; count: Small(2)
    return bytes([name_index + 1, offset, datatype, count])


XYZF = field(0, 0, 7) + field(1, 4, 7) + field(2, 8, 7)
cloud_points = struct.pack("<3f", 0.1, 0.2, 0.3) + struct.pack("<3f", float("nan"), 0, 0)
# PointCloud2, consistent sizes (flag 4; rows = 1 + height % 64): height, width,
# point_step, row_step, fields, data.
put("dds_convert", "cloud2_xyz",
    bytes([0, 4]) + le32(0, 2, 12, 24) + bytes([3]) + XYZF + cloud_points)
put("dds_convert", "cloud2_rgb_normals",
    bytes([0, 4]) + le32(0, 1, 28, 28) + bytes([7]) + XYZF + field(3, 12, 6) +
    field(5, 16, 7) + field(6, 20, 7) + field(7, 24, 7) +
    struct.pack("<3fI3f", 0.1, 0.2, 0.3, 0x00FF8000, 0, 0, 1))
put("dds_convert", "cloud2_double_rows",
    bytes([0, 4]) + le32(2, 1, 24, 24) + bytes([3]) +
    field(0, 0, 8) + field(1, 8, 8) + field(2, 16, 8) + struct.pack("<6d", 1, 2, 3, 4, 5, 6))
put("dds_convert", "cloud2_raw_sizes",
    bytes([0, 0]) + le32(1, 1, 12, 12) + bytes([3]) + XYZF + struct.pack("<3f", 1, 2, 3))
# craftscan PointCloud: strings (0 = null), view_index, point_count, 3 array lengths + values.
put("dds_convert", "cloud_msg",
    bytes([1, 4 | 1 | 2, 1, 2, 1]) + struct.pack("<iI", 3, 2) +
    struct.pack("<H", 6) + struct.pack("<6f", 1, 2, 3, 4, 5, 6) +
    struct.pack("<H", 6) + bytes(range(6)) + struct.pack("<H", 6) + struct.pack("<6f", 0, 0, 1, 0, 1, 0))
# ros Image: encoding (1 mono8, 2 bgr8, 3 32FC1), height, width, step, data.
put("dds_convert", "image_mono8", bytes([2, 4, 1]) + le32(1, 3, 3) + bytes(range(6)))
put("dds_convert", "image_32f_be", bytes([2, 4 | 1, 3]) + le32(0, 2, 8) +
    struct.pack(">2f", 1.5, -2))
put("dds_convert", "image_bgr8_padded", bytes([2, 0, 2]) + le32(2, 1, 4) + bytes(range(8)))
# StereoCapture: encoding, height, width, left byte count (uint16), left, right.
put("dds_convert", "stereo_mono8", bytes([3, 4, 1]) + le32(1, 2) + struct.pack("<H", 4) +
    bytes([1, 2, 3, 4]) + bytes([5, 6, 7, 8]))
put("dds_convert", "stereo_bgr8_raw", bytes([3, 0, 2]) + le32(1, 1) + struct.pack("<H", 3) +
    bytes([1, 2, 3]) + bytes([4, 5, 6]))
# Disparity: height, width, floats.
put("dds_convert", "disparity", bytes([4, 4]) + le32(1, 2) + struct.pack("<4f", 1, 2, float("nan"), 4))
put("dds_convert", "disparity_raw", bytes([4, 0]) + le32(1, 3) + struct.pack("<3f", 1, 2, 3))
