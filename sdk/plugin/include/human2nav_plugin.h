/*
 * human2nav plugin ABI, version 2, for plugins written in C or C++.
 *
 * Kept by hand in sync with sdk/plugin/src/abi.rs (the Rust definition is the reference; the
 * integration tests compare the sizes and field offsets this header gives a C compiler with
 * the Rust ones). See abi.rs for the full contract; in short:
 *
 *  - export `const H2nPluginEntry *human2nav_plugin_entry(void)`; its table starts with
 *    `abi_version`, which the host checks before reading anything else (it loads versions 1
 *    and 2; version 2 appended the static obstacles and the occupancy grid to H2nObservation,
 *    which a version-1 planner never reads);
 *  - tables are append-only and carry their own size (the host refuses one smaller than the
 *    table's first version or larger than 4096 bytes; slots appended later, such as the
 *    embodiment's coupled_limit and the constraint's properties, are absent from a table that
 *    ends before them; the factories of the array are struct_size apart);
 *  - function pointers may be NULL only in the optional slots: find_factory (not called by
 *    the Rust host), last_error, name, reset, coupled_limit and properties; a NULL required
 *    slot makes the host refuse the library or instance, naming the file, the table and the
 *    slot;
 *  - counts and lengths are capped by the host: 256 factories, 256-byte names and versions,
 *    4096-byte descriptions, 10000-pose plans;
 *  - strings are UTF-8 pointer + length; arrays pointer + length (+ shape); the host owns every
 *    output buffer;
 *  - every function returns an H2nStatus; after a failure, `last_error` explains it;
 *  - configuration arrives as a TOML string; unknown fields must be rejected (H2N_CONFIG);
 *  - constraint and embodiment instances must accept concurrent calls; planners are called by
 *    one thread at a time; `destroy` is called exactly once;
 *  - libraries are never unloaded.
 */
#ifndef HUMAN2NAV_PLUGIN_H
#define HUMAN2NAV_PLUGIN_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define H2N_ABI_VERSION 2u
/* The oldest version the host loads. */
#define H2N_MIN_ABI_VERSION 1u
#define H2N_ENTRY_SYMBOL "human2nav_plugin_entry"

typedef int32_t H2nStatus;
#define H2N_OK 0
#define H2N_ERROR 1
#define H2N_INVALID_ARGUMENT 2
#define H2N_CONFIG 3
#define H2N_PANIC 4
#define H2N_POISONED 5
#define H2N_BUFFER_TOO_SMALL 6
#define H2N_UNKNOWN_FACTORY 7

#define H2N_KIND_CONSTRAINT 1u
#define H2N_KIND_EMBODIMENT 2u
#define H2N_KIND_PLANNER 3u

/* UTF-8 text, not necessarily NUL-terminated. */
typedef struct H2nStr {
    const uint8_t *ptr;
    size_t len;
} H2nStr;

/* A string literal as an H2nStr. */
#define H2N_STR(literal) ((H2nStr){(const uint8_t *)(literal), sizeof(literal) - 1})

/* Host-owned text buffer: copy min(len, capacity) bytes, set len to the full length. */
typedef struct H2nBuffer {
    uint8_t *data;
    size_t capacity;
    size_t len;
} H2nBuffer;

typedef struct H2nLimits {
    double v_max;
    double v_reverse_max;
    double a_max;
    double omega_max;
    double kappa_max; /* meaningful only when has_kappa_max != 0 */
    double lateral_speed_max;
    uint32_t has_kappa_max;
    uint32_t reserved;
} H2nLimits;

typedef struct H2nGains {
    double k_x;
    double k_y;
    double k_theta;
    double k_d;
    double lookahead;
} H2nGains;

typedef struct H2nCreateArgs {
    uint32_t struct_size;
    uint32_t kind;
    H2nStr config; /* TOML */
    uint32_t has_robot; /* 1: limits, gains and footprint_radius describe the robot */
    uint32_t reserved;
    H2nLimits limits;
    H2nGains gains;
    double footprint_radius;
} H2nCreateArgs;

typedef struct H2nObject {
    void *instance;
    const void *vtable; /* H2nConstraintVTable / H2nEmbodimentVTable / H2nPlannerVTable */
} H2nObject;

typedef struct H2nFactory {
    uint32_t struct_size;
    uint32_t kind;
    H2nStr name;
    H2nStr description;
    H2nStatus (*create)(const H2nCreateArgs *args, H2nObject *out, H2nBuffer *error);
} H2nFactory;

typedef struct H2nPluginEntry {
    uint32_t abi_version;
    uint32_t struct_size;
    H2nStr name;
    H2nStr version;
    const H2nFactory *factories;
    size_t factory_count;
    const H2nFactory *(*find_factory)(uint32_t kind, H2nStr name);
} H2nPluginEntry;

typedef struct H2nPose {
    double x;
    double y;
    double theta;
} H2nPose;

typedef struct H2nTwist {
    double vx;
    double vy;
    double omega;
} H2nTwist;

typedef struct H2nAgent {
    uint64_t id;
    double position[2];
    double velocity[2];
    double radius;
    const double *history; /* history_len points [x, y], oldest first */
    size_t history_len;
} H2nAgent;

typedef struct H2nTrajBatch {
    const double *data; /* [batch, horizon, dim], dim == 3 */
    size_t len;
    size_t batch;
    size_t horizon;
    size_t dim;
} H2nTrajBatch;

typedef struct H2nF64Out {
    double *data;
    size_t len;
} H2nF64Out;

typedef struct H2nConstraintContext {
    uint32_t struct_size;
    uint32_t reserved;
    double dt;
    H2nLimits limits;
    H2nTwist initial_velocity;
    const H2nAgent *agents;
    size_t agent_count;
} H2nConstraintContext;

typedef struct H2nConstraintVTable {
    uint32_t struct_size;
    uint32_t reserved;
    void (*destroy)(void *instance);
    void (*last_error)(void *instance, H2nBuffer *out);
    H2nStr (*name)(void *instance);
    /* Adds cost[b] (cost.len == batch) and the gradient (grad.len == batch->len). */
    H2nStatus (*evaluate)(void *instance, const H2nTrajBatch *batch,
                          const H2nConstraintContext *ctx, H2nF64Out cost, H2nF64Out grad);
    /* Optional (appended after the table's first version): writes the H2N_CONSTRAINT_* bits
     * into *out; asked once, when the instance is created. */
    H2nStatus (*properties)(void *instance, uint32_t *out);
} H2nConstraintVTable;

/* The cost of a trajectory is never negative, is finite for finite poses, and does not depend
 * on the other trajectories of its batch (to the bit): a planner may then skip the term for
 * candidates whose score already loses without it. */
#define H2N_CONSTRAINT_SEPARABLE_NONNEGATIVE 1u

typedef struct H2nRobotState {
    H2nPose pose;
    H2nTwist velocity;
} H2nRobotState;

typedef struct H2nPlanView {
    double t0;
    double dt;
    const H2nPose *poses;
    size_t pose_count;
} H2nPlanView;

/* A coupled twist limit v*|vx| + lateral*|vy| + omega*|omega| <= max (a tracked base's track
 * speed). All zeros means none. */
typedef struct H2nCoupledLimit {
    double v;
    double lateral;
    double omega;
    double max;
} H2nCoupledLimit;

typedef struct H2nEmbodimentVTable {
    uint32_t struct_size;
    uint32_t reserved;
    void (*destroy)(void *instance);
    void (*last_error)(void *instance, H2nBuffer *out);
    H2nStr (*name)(void *instance);
    H2nStatus (*holonomic)(void *instance, uint32_t *out);
    H2nStatus (*saturate)(void *instance, const H2nRobotState *state, const H2nTwist *cmd,
                          double dt, H2nTwist *out);
    H2nStatus (*step)(void *instance, const H2nRobotState *state, const H2nTwist *cmd,
                      double dt, H2nRobotState *out);
    H2nStatus (*track)(void *instance, const H2nRobotState *state, const H2nPlanView *plan,
                       double t, H2nTwist *out);
    /* Optional, appended after the first version of this table (a struct_size that ends
     * before it: none). Writes the coupled limit into `out`, zeroed by the host; called once. */
    H2nStatus (*coupled_limit)(void *instance, H2nCoupledLimit *out);
} H2nEmbodimentVTable;

/* H2nObstacle.kind (version 2). */
#define H2N_OBSTACLE_CIRCLE 0u  /* centre (x0, y0), radius */
#define H2N_OBSTACLE_SEGMENT 1u /* from (x0, y0) to (x1, y1) */
#define H2N_OBSTACLE_POLYGON 2u /* vertex_count >= 3 vertices, x, y pairs at `vertices` */

/* A static obstacle in the world frame; fields its kind does not use are zero (version 2). */
typedef struct H2nObstacle {
    uint32_t kind;
    uint32_t reserved;
    double x0;
    double y0;
    double x1;
    double y1;
    double radius;
    const double *vertices;
    size_t vertex_count;
} H2nObstacle;

/* An occupancy grid as nav_msgs/OccupancyGrid: row-major cells, -1 unknown, 0..100 (version 2). */
typedef struct H2nOccupancyGrid {
    H2nPose origin;
    double resolution;
    size_t width;
    size_t height;
    const int8_t *data;
    int32_t occupied_threshold;
    uint32_t reserved;
} H2nOccupancyGrid;

typedef struct H2nObservation {
    uint32_t struct_size;
    uint32_t reserved;
    double time;
    H2nPose ego;
    H2nTwist ego_velocity;
    double goal[2];
    const H2nAgent *agents;
    size_t agent_count;
    /* Version 2: a version-1 plugin reads the fields above only. */
    const H2nObstacle *obstacles; /* NULL when obstacle_count == 0 */
    size_t obstacle_count;
    const H2nOccupancyGrid *occupancy; /* NULL when there is no grid */
} H2nObservation;

typedef struct H2nPlanOut {
    double t0;
    double dt;
    H2nPose *poses; /* capacity entries, host-owned */
    size_t capacity;
    size_t len;
    uint32_t fallback;
    uint32_t reserved;
    H2nBuffer note;
} H2nPlanOut;

typedef struct H2nPlannerVTable {
    uint32_t struct_size;
    uint32_t reserved;
    void (*destroy)(void *instance);
    void (*last_error)(void *instance, H2nBuffer *out);
    H2nStr (*name)(void *instance);
    H2nStatus (*reset)(void *instance);
    H2nStatus (*plan)(void *instance, const H2nObservation *obs, H2nPlanOut *out);
    H2nStatus (*last_plan)(void *instance, H2nPlanOut *out);
} H2nPlannerVTable;

#ifdef __cplusplus
}
#endif

#endif /* HUMAN2NAV_PLUGIN_H */
