/*
 * glint.h - C and C++ interface to Glint's poses and sweeps (libglint).
 *
 * glintd publishes the robot's pose and its own health over iceoryx2 0.10.0 shared memory, on
 * the services glint/<domain>/{odom,map,predicted,status}, each sweep's points on
 * glint/<domain>/sweep, and takes initial-pose hints on
 * glint/<domain>/initial_pose; ipc/README.md in the Glint sources is
 * the contract (layouts, units, frames, flags, behaviour across daemon restarts). This header
 * mirrors its payload structs byte for byte: the static assertions below check sizes and offsets
 * at compile time, and Glint's tests compare them with the Rust structs.
 *
 * Usable from C99, C11 and C++. Link with -lglint (pkg-config glint).
 *
 * Conventions:
 *  - Every function returns a result code (GLINT_OK, GLINT_NO_DATA, GLINT_TIMEOUT, or a
 *    negative GLINT_ERR_*), except the two functions returning strings, which cannot fail.
 *  - After any call, glint_*_last_error(handle) says why it did not return GLINT_OK ("" after
 *    GLINT_OK). The text stays valid until the next call on that handle. The one call without
 *    a handle, glint_send_initial_pose, writes its message into a buffer of the caller's.
 *  - A handle is used by one thread at a time (it may move between threads) and never after
 *    close. Different handles are independent: libglint keeps no global state of its own
 *    (iceoryx2 underneath reads its configuration file once per process).
 *  - Nothing blocks except the *_wait functions, which sleep on the event service glintd
 *    notifies after every message (no polling while connected), glint_sweep_subscriber_wait,
 *    which polls (the sweep service has no event service; see there), and
 *    glint_send_initial_pose (0.5 s, see there).
 *  - Strings are NUL-terminated ASCII. Domains are 1-64 characters from [A-Za-z0-9_-].
 */
#ifndef GLINT_H
#define GLINT_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---- Result codes ------------------------------------------------------------------------ */

/** Success; the caller's struct holds a new message. */
#define GLINT_OK 0
/** Not an error: no unread message (take); the caller's struct is untouched. */
#define GLINT_NO_DATA 1
/** Not an error: nothing arrived within the timeout (wait); the caller's struct is untouched. */
#define GLINT_TIMEOUT 2
/** A null pointer, an invalid domain, an unknown stream name, or a sweep larger than the buffer
 *  given for it (see glint_sweep_subscriber_take). Retrying the same call cannot help. */
#define GLINT_ERR_INVALID_ARGUMENT (-1)
/** The service does not exist: glintd is not running, runs with another domain, or uses another
 *  iceoryx2 root. The handle keeps trying to connect on each later call. */
#define GLINT_ERR_NOT_RUNNING (-2)
/** The service exists but speaks another contract (another payload version, a publisher that
 *  is not glintd). The handle keeps trying. */
#define GLINT_ERR_INCOMPATIBLE (-3)
/** Another iceoryx2 failure (permissions, shared memory). The handle reconnects next call. */
#define GLINT_ERR_IPC (-4)
/** A signal interrupted the wait; call again. */
#define GLINT_ERR_INTERRUPTED (-5)
/** A bug inside libglint, caught before it could crash the caller. */
#define GLINT_ERR_INTERNAL (-6)

/* ---- Payloads (ipc/README.md) ---------------------------------------------------------- */

/** Status bits of glint_pose_v1.status and glint_status_v1.flags; bits 9-31 are reserved
 *  (written 0, to be ignored). */
#define GLINT_STATUS_INITIALISING 0x01u /* starting up, no local map yet: do not steer by it */
#define GLINT_STATUS_TRACKING 0x02u     /* scan matching converged on this sweep */
#define GLINT_STATUS_DEGENERATE 0x04u   /* a direction is poorly constrained: see covariance */
#define GLINT_STATUS_LOST 0x08u         /* tracking lost; pose not measured: the last good one
                                           or its constant-velocity prediction */
#define GLINT_STATUS_LOOP_CLOSED 0x10u  /* map corrected; this map pose may jump */
#define GLINT_STATUS_PREDICTED 0x20u    /* extrapolated, not measured */
#define GLINT_STATUS_SENSOR_SILENT 0x40u /* no packets from the sensor recently */
#define GLINT_STATUS_RELOCALISING 0x80u /* map pose not verified in the saved map */
#define GLINT_STATUS_FOREIGN_SENSOR 0x100u /* another sensor's packets refused (shared network) */

/** Values of glint_pose_v1.frame; treat other values as unknown. */
#define GLINT_FRAME_ODOM 0u
#define GLINT_FRAME_MAP 1u

/** iceoryx2 type names of the payloads. */
#define GLINT_POSE_TYPE_NAME "glint::PoseV1"
#define GLINT_STATUS_TYPE_NAME "glint::StatusV1"

/** One pose of base_link (glint::PoseV1, 424 bytes, alignment 8). */
typedef struct glint_pose_v1 {
    uint64_t sequence;           /*   0: per-stream counter, +1 per message; a gap = missed */
    uint64_t timestamp_ns;       /*   8: instant the pose describes, ns since the Unix epoch */
    double position[3];          /*  16: x, y, z of base_link in `frame`, m */
    double orientation[4];       /*  40: unit quaternion x, y, z, w (scalar last) */
    double linear_velocity[3];   /*  72: m/s, body frame */
    double angular_velocity[3];  /*  96: rad/s, body frame */
    double covariance[36];       /* 120: 6x6 row-major over x, y, z, roll, pitch, yaw */
    float quality;               /* 408: match quality, 0..1 */
    uint32_t frame;              /* 412: GLINT_FRAME_ODOM or GLINT_FRAME_MAP */
    uint32_t status;             /* 416: GLINT_STATUS_* bits */
    uint32_t _pad0;              /* 420: padding, always 0 */
} glint_pose_v1;

/** Daemon health, about once a second (glint::StatusV1, 80 bytes, alignment 8). */
typedef struct glint_status_v1 {
    uint64_t sequence;          /*  0: counter of the status stream */
    uint64_t timestamp_ns;      /*  8: when taken, ns since the Unix epoch */
    uint64_t sweeps_processed;  /* 16: total since the daemon started */
    uint64_t sweeps_dropped;    /* 24: whole sweeps dropped because a stage fell behind */
    uint64_t packets_received;  /* 32 */
    uint64_t packets_dropped;   /* 40 */
    uint64_t packets_malformed; /* 48 */
    float sweep_rate_hz;        /* 56: over the last reporting window */
    float packet_rate_hz;       /* 60 */
    float latency_median_ms;    /* 64: last packet of a sweep received -> pose published */
    float latency_p99_ms;       /* 68 */
    uint32_t flags;             /* 72: GLINT_STATUS_* bits, as in the latest pose */
    uint32_t _pad0;             /* 76: padding, always 0 */
} glint_status_v1;

/* Compile-time layout checks: C11 and C++11 have static assertions; C99 gets an array whose size
 * is negative when the condition is false. */
#if defined(__cplusplus) && __cplusplus >= 201103L
#define GLINT_STATIC_ASSERT(cond, tag) static_assert(cond, #tag)
#elif defined(__STDC_VERSION__) && __STDC_VERSION__ >= 201112L
#define GLINT_STATIC_ASSERT(cond, tag) _Static_assert(cond, #tag)
#else
#define GLINT_STATIC_ASSERT(cond, tag) typedef char glint_static_assert_##tag[(cond) ? 1 : -1]
#endif

GLINT_STATIC_ASSERT(sizeof(glint_pose_v1) == 424, pose_size);
GLINT_STATIC_ASSERT(offsetof(glint_pose_v1, sequence) == 0, pose_sequence);
GLINT_STATIC_ASSERT(offsetof(glint_pose_v1, timestamp_ns) == 8, pose_timestamp_ns);
GLINT_STATIC_ASSERT(offsetof(glint_pose_v1, position) == 16, pose_position);
GLINT_STATIC_ASSERT(offsetof(glint_pose_v1, orientation) == 40, pose_orientation);
GLINT_STATIC_ASSERT(offsetof(glint_pose_v1, linear_velocity) == 72, pose_linear_velocity);
GLINT_STATIC_ASSERT(offsetof(glint_pose_v1, angular_velocity) == 96, pose_angular_velocity);
GLINT_STATIC_ASSERT(offsetof(glint_pose_v1, covariance) == 120, pose_covariance);
GLINT_STATIC_ASSERT(offsetof(glint_pose_v1, quality) == 408, pose_quality);
GLINT_STATIC_ASSERT(offsetof(glint_pose_v1, frame) == 412, pose_frame);
GLINT_STATIC_ASSERT(offsetof(glint_pose_v1, status) == 416, pose_status);
GLINT_STATIC_ASSERT(offsetof(glint_pose_v1, _pad0) == 420, pose_pad0);

GLINT_STATIC_ASSERT(sizeof(glint_status_v1) == 80, status_size);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, sequence) == 0, status_sequence);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, timestamp_ns) == 8, status_timestamp_ns);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, sweeps_processed) == 16, status_sweeps_processed);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, sweeps_dropped) == 24, status_sweeps_dropped);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, packets_received) == 32, status_packets_received);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, packets_dropped) == 40, status_packets_dropped);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, packets_malformed) == 48, status_packets_malformed);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, sweep_rate_hz) == 56, status_sweep_rate_hz);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, packet_rate_hz) == 60, status_packet_rate_hz);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, latency_median_ms) == 64, status_latency_median);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, latency_p99_ms) == 68, status_latency_p99);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, flags) == 72, status_flags);
GLINT_STATIC_ASSERT(offsetof(glint_status_v1, _pad0) == 76, status_pad0);

/* ---- Sweep payloads (ipc/README.md, "Sweeps") ------------------------------------------- */

/** Bits of glint_sweep_point_v1.label: what the front end chose the point as (several may be set;
 *  none = not a feature). Bits 3-7 are reserved (written 0, to be ignored). */
#define GLINT_POINT_EDGE 0x01u      /* a geometric corner or an intensity boundary */
#define GLINT_POINT_PLANE 0x02u     /* a plane point */
#define GLINT_POINT_INTENSITY 0x04u /* a strong reflectivity gradient */

/** Points a sweep sample holds: no sweep glintd publishes has more. A buffer of this many
 *  glint_sweep_point_v1 (3 MiB) fits any sweep. */
#define GLINT_SWEEP_MAX_POINTS 131072

/** How often glint_sweep_subscriber_wait looks for a new sweep, in milliseconds. */
#define GLINT_SWEEP_POLL_INTERVAL_MS 5

/** iceoryx2 type names of the sweep service's user header and slice elements. */
#define GLINT_SWEEP_HEADER_TYPE_NAME "glint::SweepHeaderV1"
#define GLINT_SWEEP_POINT_TYPE_NAME "glint::SweepPointV1"

/** One return of a sweep (glint::SweepPointV1, 24 bytes, alignment 4). */
typedef struct glint_sweep_point_v1 {
    float position[3];      /*  0: x, y, z in base_link at the header's timestamp_ns, m */
    float intensity;        /* 12: calibrated reflectivity (about 0..1); NaN where not calibrated */
    int32_t time_offset_ns; /* 16: firing time - header.sensor_time_ns, ns (<= 0) */
    uint16_t ring;          /* 20: laser ring, 0 = lowest beam */
    uint8_t reflectivity;   /* 22: the sensor's raw byte: 0-100 diffuse, 101-255 retro-reflective */
    uint8_t label;          /* 23: GLINT_POINT_* bits; 0 = not a feature */
} glint_sweep_point_v1;

/** A sweep's header (glint::SweepHeaderV1, 136 bytes, alignment 8). The points are deskewed to
 *  timestamp_ns: the odom pose with the same stamp is where base_link was. */
typedef struct glint_sweep_header_v1 {
    uint64_t timestamp_ns;         /*   0: the sweep's last firing, on the poses' time base, ns */
    uint64_t sensor_time_ns;       /*   8: the same instant on the sensor's clock, ns */
    uint64_t sequence;             /*  16: +1 per sweep published; a gap = not published or lost */
    uint32_t point_count;          /*  24: points in the sweep */
    uint32_t flags;                /*  28: GLINT_STATUS_* bits of the sweep's odom pose */
    double sensor_twist[6];        /*  32: deskewing twist, sensor frame: w (rad/s), v (m/s) */
    double sensor_position[3];     /*  80: mounting base_link <- sensor: translation, m */
    double sensor_orientation[4];  /* 104: mounting rotation, unit quaternion x, y, z, w */
} glint_sweep_header_v1;

GLINT_STATIC_ASSERT(sizeof(glint_sweep_point_v1) == 24, sweep_point_size);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_point_v1, position) == 0, sweep_point_position);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_point_v1, intensity) == 12, sweep_point_intensity);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_point_v1, time_offset_ns) == 16, sweep_point_time_offset);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_point_v1, ring) == 20, sweep_point_ring);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_point_v1, reflectivity) == 22, sweep_point_reflectivity);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_point_v1, label) == 23, sweep_point_label);

GLINT_STATIC_ASSERT(sizeof(glint_sweep_header_v1) == 136, sweep_header_size);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_header_v1, timestamp_ns) == 0, sweep_header_timestamp_ns);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_header_v1, sensor_time_ns) == 8, sweep_header_sensor_time);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_header_v1, sequence) == 16, sweep_header_sequence);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_header_v1, point_count) == 24, sweep_header_point_count);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_header_v1, flags) == 28, sweep_header_flags);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_header_v1, sensor_twist) == 32, sweep_header_twist);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_header_v1, sensor_position) == 80, sweep_header_position);
GLINT_STATIC_ASSERT(offsetof(glint_sweep_header_v1, sensor_orientation) == 104,
                    sweep_header_orientation);

/* ---- Pose subscriber ------------------------------------------------------------------- */

/** Opaque handle on one pose stream of one domain. */
typedef struct glint_pose_subscriber glint_pose_subscriber;

/** Subscribes to glint/<domain>/<stream> (stream: "odom", "map" or "predicted") and its event
 *  service. *out receives a handle whatever the result (except when out is NULL): GLINT_OK =
 *  connected; GLINT_ERR_NOT_RUNNING and other retryable errors = not yet connected, and the
 *  handle connects on a later take/wait once glintd is up; GLINT_ERR_INVALID_ARGUMENT = the
 *  handle only reports why. Read last_error, and always close the handle. */
int glint_pose_subscriber_open(const char *domain, const char *stream,
                               glint_pose_subscriber **out);

/** Copies the oldest unread pose into *out without blocking: GLINT_OK, or GLINT_NO_DATA when
 *  nothing is unread (up to 16 poses queue; older ones are overwritten, seen as a gap in
 *  sequence). */
int glint_pose_subscriber_take(glint_pose_subscriber *sub, glint_pose_v1 *out);

/** Copies the newest pose into *out without blocking, discarding older unread ones: GLINT_OK or
 *  GLINT_NO_DATA. For a controller that only wants the current pose. */
int glint_pose_subscriber_take_latest(glint_pose_subscriber *sub, glint_pose_v1 *out);

/** Copies the oldest unread pose into *out, sleeping on the event service until one arrives or
 *  timeout_ms passes (GLINT_TIMEOUT; last_error then says how long ago the last pose came).
 *  While not connected it retries the connection every 20 ms within the timeout. */
int glint_pose_subscriber_wait(glint_pose_subscriber *sub, uint32_t timeout_ms,
                               glint_pose_v1 *out);

/** Why the last call on sub did not return GLINT_OK ("" if it did). Never NULL; valid until the
 *  next call on sub. */
const char *glint_pose_subscriber_last_error(const glint_pose_subscriber *sub);

/** Releases the handle and its iceoryx2 ports. NULL is allowed. Returns GLINT_OK (or
 *  GLINT_ERR_INTERNAL if releasing failed inside the library; the handle is gone either way). */
int glint_pose_subscriber_close(glint_pose_subscriber *sub);

/* ---- Status subscriber ----------------------------------------------------------------- */

/** Opaque handle on glint/<domain>/status. */
typedef struct glint_status_subscriber glint_status_subscriber;

/** Subscribes to glint/<domain>/status; results and handle as glint_pose_subscriber_open. */
int glint_status_subscriber_open(const char *domain, glint_status_subscriber **out);

/** Copies the newest status into *out without blocking: GLINT_OK or GLINT_NO_DATA. */
int glint_status_subscriber_take_latest(glint_status_subscriber *sub, glint_status_v1 *out);

/** Copies the oldest unread status into *out, sleeping on the event service up to timeout_ms:
 *  GLINT_OK or GLINT_TIMEOUT (glintd publishes status about once a second). */
int glint_status_subscriber_wait(glint_status_subscriber *sub, uint32_t timeout_ms,
                                 glint_status_v1 *out);

/** Why the last call on sub did not return GLINT_OK ("" if it did). Never NULL. */
const char *glint_status_subscriber_last_error(const glint_status_subscriber *sub);

/** Releases the handle; as glint_pose_subscriber_close. */
int glint_status_subscriber_close(glint_status_subscriber *sub);

/* ---- Sweep subscriber ------------------------------------------------------------------ */

/** Opaque handle on glint/<domain>/sweep. */
typedef struct glint_sweep_subscriber glint_sweep_subscriber;

/** Subscribes to glint/<domain>/sweep (published when glintd runs with [ipc] sweeps = true, the
 *  default); results and handle as glint_pose_subscriber_open: *out receives a handle whatever
 *  the result (except when out is NULL), which connects on a later take/wait when glintd is not
 *  up yet and outlives a glintd restart. Like every handle, used by one thread at a time. Read
 *  last_error, and always close the handle. */
int glint_sweep_subscriber_open(const char *domain, glint_sweep_subscriber **out);

/** Copies the oldest unread sweep without blocking: its header into *header and its
 *  header->point_count points into points[0 .. point_count-1] (the rest of the buffer is left
 *  as it was). The caller owns both buffers; nothing is kept after the call returns. Returns
 *  GLINT_OK, or GLINT_NO_DATA when nothing is unread (both buffers untouched). Up to 2 sweeps
 *  queue; older ones are overwritten, seen as a gap in sequence.
 *
 *  capacity is how many glint_sweep_point_v1 fit in points; points may be NULL only when capacity is
 *  0 (to read headers alone). A sweep with more points than capacity is consumed all the same:
 *  the result is GLINT_ERR_INVALID_ARGUMENT, *header is filled (point_count says the size
 *  needed, and last_error names it), the points buffer is untouched, and the next call returns
 *  the next sweep. A buffer of GLINT_SWEEP_MAX_POINTS points never is too small.
 *  GLINT_ERR_INVALID_ARGUMENT also for a NULL sub, header, or points with capacity > 0 (nothing
 *  consumed, nothing written). */
int glint_sweep_subscriber_take(glint_sweep_subscriber *sub, glint_sweep_header_v1 *header,
                                glint_sweep_point_v1 *points, size_t capacity);

/** As glint_sweep_subscriber_take, but waits for a sweep up to timeout_ms (then GLINT_TIMEOUT;
 *  last_error says how long ago the last sweep came). The sweep service has no event service,
 *  so this polls: it looks every GLINT_SWEEP_POLL_INTERVAL_MS (5 ms) and sleeps in between, which
 *  adds up to 5 ms to a sweep's delivery. A signal does not end the wait early (never
 *  GLINT_ERR_INTERRUPTED): keep timeout_ms short if the caller must react to one. While not
 *  connected it retries the connection every 20 ms within the timeout. */
int glint_sweep_subscriber_wait(glint_sweep_subscriber *sub, uint32_t timeout_ms,
                                glint_sweep_header_v1 *header, glint_sweep_point_v1 *points,
                                size_t capacity);

/** Why the last call on sub did not return GLINT_OK ("" if it did). Never NULL; valid until the
 *  next call on sub. */
const char *glint_sweep_subscriber_last_error(const glint_sweep_subscriber *sub);

/** Releases the handle; as glint_pose_subscriber_close. */
int glint_sweep_subscriber_close(glint_sweep_subscriber *sub);

/* ---- Initial-pose hint ------------------------------------------------------------------- */

/** iceoryx2 type name of the hint payload (ipc/README.md, "InitialPose"). */
#define GLINT_INITIAL_POSE_TYPE_NAME "glint::InitialPoseV1"

/** Tells glintd roughly where the robot is in the saved site map, so that its localiser searches
 *  near there instead of the whole map: base_link at (x, y) metres on the floor of the map
 *  frame, heading yaw radians about its z axis (0 = facing +x), within about position_sigma
 *  metres (one standard deviation; 0 = unknown).
 *
 *  One-shot: opens glint/<domain>/initial_pose (created by glintd; never created here), sends
 *  the hint stamped with the current time, keeps the port open 0.5 s so glintd takes it, closes.
 *  Blocks for those 0.5 s on success; fails at once otherwise.
 *
 *  Returns GLINT_OK; GLINT_ERR_INVALID_ARGUMENT for a bad domain, a non-finite number or a
 *  negative position_sigma (nothing is sent); GLINT_ERR_NOT_RUNNING when no glintd runs with
 *  this domain; GLINT_ERR_INCOMPATIBLE or GLINT_ERR_IPC otherwise. Why it failed is written to
 *  error (NUL-terminated, truncated to error_size bytes; "" on GLINT_OK) unless error is NULL
 *  or error_size is 0. Needs no handle and keeps no state. */
int glint_send_initial_pose(const char *domain, double x, double y, double yaw,
                            double position_sigma, char *error, size_t error_size);

/* ---- Codes --------------------------------------------------------------------------------- */

/** The name of a result code ("GLINT_ERR_NOT_RUNNING"), or "GLINT_UNKNOWN_CODE". Static. */
const char *glint_code_name(int code);

#ifdef __cplusplus
} /* extern "C" */
#endif

#endif /* GLINT_H */
