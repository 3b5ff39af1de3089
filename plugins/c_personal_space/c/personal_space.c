/*
 * personal_space_c: the personal-space clearance term of plugins/personal_space, in C.
 *
 * For pose k (time k*dt) and agent j predicted at q = p_j + v_j*k*dt:
 *   d      = sqrt(|x_k - q|^2 + eps^2)          eps = 1e-6 m
 *   d_safe = robot_radius + r_j + personal_space
 *   z      = gamma * (1 - d/d_safe + delta)
 *   cost_b = (1/T) sum_k sum_j softplus(z)/gamma             (pairs with z < -36 skipped)
 *   dcost_b/dx_k = -(1/T) sum_j sigmoid(z) (x_k - q) / (d d_safe),   dcost_b/dtheta_k = 0
 *
 * Configuration: a flat TOML table of the keys below (numbers or booleans; comments allowed);
 * anything else, including unknown keys, tables, arrays and strings, is rejected.
 *   personal_space = 0.5, robot_radius = <footprint radius, else 0.3>, gamma = 10.0,
 *   delta = 0.05, predict = true
 */
#include "human2nav_plugin.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define EPSILON 1e-6
#define SKIP_BELOW (-36.0)
#define DEFAULT_ROBOT_RADIUS 0.3
#define ERROR_CAPACITY 256

typedef struct Term {
    double personal_space;
    double robot_radius;
    double gamma;
    double delta;
    int predict;
    pthread_mutex_t lock; /* guards last_error: evaluate may run on several threads */
    char last_error[ERROR_CAPACITY];
} Term;

static const char TERM_NAME[] = "personal_space_c";

/* ----------------------------------------------------------------------------------------- */
/* Text helpers                                                                               */

static void write_text(H2nBuffer *out, const char *text) {
    if (out == NULL) return;
    size_t len = strlen(text);
    size_t n = len < out->capacity ? len : out->capacity;
    if (n > 0 && out->data != NULL) memcpy(out->data, text, n);
    out->len = len;
}

static void set_error(Term *t, const char *fmt, const char *detail) {
    pthread_mutex_lock(&t->lock);
    snprintf(t->last_error, sizeof t->last_error, fmt, detail);
    pthread_mutex_unlock(&t->lock);
}

/* ----------------------------------------------------------------------------------------- */
/* A minimal TOML reader: `key = number|true|false` lines, `#` comments, blank lines.          */

static const char *skip_space(const char *p, const char *end) {
    while (p < end && (*p == ' ' || *p == '\t')) p++;
    return p;
}

/* Parses the config into `t`; on failure writes a message into `err` and returns 0. */
static int parse_config(const char *text, size_t len, Term *t, int has_robot_radius,
                        char *err, size_t err_cap) {
    int seen[5] = {0, 0, 0, 0, 0};
    static const char *const keys[5] = {"personal_space", "robot_radius", "gamma", "delta",
                                        "predict"};
    const char *p = text;
    const char *end = text + len;
    int line = 0;
    (void)has_robot_radius;
    while (p < end) {
        line++;
        const char *eol = memchr(p, '\n', (size_t)(end - p));
        if (eol == NULL) eol = end;
        const char *q = skip_space(p, eol);
        if (q < eol && *q != '#' && *q != '\r') {
            const char *key = q;
            while (q < eol && (isalnum((unsigned char)*q) || *q == '_')) q++;
            size_t key_len = (size_t)(q - key);
            q = skip_space(q, eol);
            if (key_len == 0 || q >= eol || *q != '=') {
                snprintf(err, err_cap, "line %d: expected `key = value` (only a flat table of "
                         "numbers and booleans is supported)", line);
                return 0;
            }
            q = skip_space(q + 1, eol);
            const char *val = q;
            while (q < eol && *q != '#' && *q != ' ' && *q != '\t' && *q != '\r') q++;
            size_t val_len = (size_t)(q - val);
            q = skip_space(q, eol);
            if (q < eol && *q != '#' && *q != '\r') {
                snprintf(err, err_cap, "line %d: unexpected text after the value", line);
                return 0;
            }
            int which = -1;
            for (int i = 0; i < 5; i++) {
                if (strlen(keys[i]) == key_len && strncmp(keys[i], key, key_len) == 0) which = i;
            }
            if (which < 0) {
                snprintf(err, err_cap, "unknown field(s) `%.*s`", (int)key_len, key);
                return 0;
            }
            if (seen[which]) {
                snprintf(err, err_cap, "line %d: duplicate key `%s`", line, keys[which]);
                return 0;
            }
            seen[which] = 1;
            char buf[64];
            if (val_len == 0 || val_len >= sizeof buf) {
                snprintf(err, err_cap, "line %d: `%s`: missing or overlong value", line,
                         keys[which]);
                return 0;
            }
            memcpy(buf, val, val_len);
            buf[val_len] = '\0';
            if (which == 4) {
                if (strcmp(buf, "true") == 0) {
                    t->predict = 1;
                } else if (strcmp(buf, "false") == 0) {
                    t->predict = 0;
                } else {
                    snprintf(err, err_cap, "line %d: `predict` must be true or false", line);
                    return 0;
                }
            } else {
                char *stop = NULL;
                errno = 0;
                double v = strtod(buf, &stop);
                if (stop == buf || *stop != '\0' || errno != 0) {
                    snprintf(err, err_cap, "line %d: `%s` must be a number", line, keys[which]);
                    return 0;
                }
                if (which == 0) t->personal_space = v;
                if (which == 1) t->robot_radius = v;
                if (which == 2) t->gamma = v;
                if (which == 3) t->delta = v;
            }
        }
        p = eol < end ? eol + 1 : end;
    }
    if (!(isfinite(t->personal_space) && t->personal_space >= 0.0)) {
        snprintf(err, err_cap, "personal_space: must be finite and >= 0");
        return 0;
    }
    if (!(isfinite(t->robot_radius) && t->robot_radius >= 0.0)) {
        snprintf(err, err_cap, "robot_radius: must be finite and >= 0");
        return 0;
    }
    if (!(isfinite(t->gamma) && t->gamma > 0.0)) {
        snprintf(err, err_cap, "gamma: must be finite and > 0");
        return 0;
    }
    if (!(isfinite(t->delta) && t->delta >= 0.0 && t->delta < 1.0)) {
        snprintf(err, err_cap, "delta: must be in [0, 1)");
        return 0;
    }
    return 1;
}

/* ----------------------------------------------------------------------------------------- */
/* The constraint                                                                              */

static double softplus(double x) { return x > 0.0 ? x + log1p(exp(-x)) : log1p(exp(x)); }

static double sigmoid(double x) {
    if (x >= 0.0) return 1.0 / (1.0 + exp(-x));
    double e = exp(x);
    return e / (1.0 + e);
}

static void term_destroy(void *instance) {
    Term *t = instance;
    if (t == NULL) return;
    pthread_mutex_destroy(&t->lock);
    free(t);
}

static void term_last_error(void *instance, H2nBuffer *out) {
    Term *t = instance;
    if (t == NULL) {
        write_text(out, "instance is null");
        return;
    }
    pthread_mutex_lock(&t->lock);
    write_text(out, t->last_error);
    pthread_mutex_unlock(&t->lock);
}

static H2nStr term_name(void *instance) {
    (void)instance;
    return H2N_STR(TERM_NAME);
}

static H2nStatus term_evaluate(void *instance, const H2nTrajBatch *batch,
                               const H2nConstraintContext *ctx, H2nF64Out cost, H2nF64Out grad) {
    Term *t = instance;
    if (t == NULL) return H2N_INVALID_ARGUMENT;
    if (batch == NULL || ctx == NULL) {
        set_error(t, "%s is null", batch == NULL ? "batch" : "context");
        return H2N_INVALID_ARGUMENT;
    }
    if (ctx->struct_size < sizeof(H2nConstraintContext)) {
        set_error(t, "%s", "constraint context is from an older host");
        return H2N_INVALID_ARGUMENT;
    }
    if (batch->dim != 3 || batch->len != batch->batch * batch->horizon * 3 ||
        cost.len != batch->batch || grad.len != batch->len) {
        set_error(t, "%s", "shape mismatch between batch, cost and gradient");
        return H2N_INVALID_ARGUMENT;
    }
    if ((batch->len > 0 && (batch->data == NULL || grad.data == NULL)) ||
        (cost.len > 0 && cost.data == NULL) ||
        (ctx->agent_count > 0 && ctx->agents == NULL)) {
        set_error(t, "%s", "null array with a non-zero length");
        return H2N_INVALID_ARGUMENT;
    }
    if (t->predict && !(isfinite(ctx->dt) && ctx->dt > 0.0)) {
        set_error(t, "%s", "dt must be finite and positive");
        return H2N_ERROR;
    }
    size_t T = batch->horizon;
    if (T == 0 || ctx->agent_count == 0) return H2N_OK;
    double inv_t = 1.0 / (double)T;
    double inv_gamma = 1.0 / t->gamma;
    double dt = t->predict ? ctx->dt : 0.0;
    for (size_t b = 0; b < batch->batch; b++) {
        const double *traj = batch->data + b * T * 3;
        double *g = grad.data + b * T * 3;
        double c = 0.0;
        for (size_t k = 0; k < T; k++) {
            double x = traj[3 * k], y = traj[3 * k + 1];
            double time = (double)k * dt;
            for (size_t j = 0; j < ctx->agent_count; j++) {
                const H2nAgent *a = &ctx->agents[j];
                double d_safe = t->robot_radius + a->radius + t->personal_space;
                if (d_safe <= 0.0) continue;
                double dx = x - (a->position[0] + a->velocity[0] * time);
                double dy = y - (a->position[1] + a->velocity[1] * time);
                double d = sqrt(dx * dx + dy * dy + EPSILON * EPSILON);
                double z = t->gamma * (1.0 - d / d_safe + t->delta);
                if (z < SKIP_BELOW) continue;
                c += inv_gamma * softplus(z);
                double w = -inv_t * sigmoid(z) / (d * d_safe);
                g[3 * k] += w * dx;
                g[3 * k + 1] += w * dy;
            }
        }
        cost.data[b] += c * inv_t;
    }
    return H2N_OK;
}

/* A sum of softplus terms per trajectory: never negative, finite for finite poses, and each
 * trajectory's cost is computed from it alone. */
static H2nStatus term_properties(void *instance, uint32_t *out) {
    if (instance == NULL || out == NULL) return H2N_INVALID_ARGUMENT;
    *out = H2N_CONSTRAINT_SEPARABLE_NONNEGATIVE;
    return H2N_OK;
}

static const H2nConstraintVTable TERM_VTABLE = {
    sizeof(H2nConstraintVTable), 0, term_destroy, term_last_error, term_name, term_evaluate,
    term_properties,
};

static H2nStatus create_term(const H2nCreateArgs *args, H2nObject *out, H2nBuffer *error) {
    char err[ERROR_CAPACITY];
    if (args == NULL || out == NULL) {
        write_text(error, "create args or output is null");
        return H2N_INVALID_ARGUMENT;
    }
    if (args->struct_size < sizeof(H2nCreateArgs) || args->kind != H2N_KIND_CONSTRAINT) {
        write_text(error, "create args of another ABI revision or kind");
        return H2N_INVALID_ARGUMENT;
    }
    if (args->config.len > 0 && args->config.ptr == NULL) {
        write_text(error, "config is null");
        return H2N_INVALID_ARGUMENT;
    }
    Term *t = calloc(1, sizeof *t);
    if (t == NULL) {
        write_text(error, "out of memory");
        return H2N_ERROR;
    }
    t->personal_space = 0.5;
    t->robot_radius = args->has_robot ? args->footprint_radius : DEFAULT_ROBOT_RADIUS;
    t->gamma = 10.0;
    t->delta = 0.05;
    t->predict = 1;
    if (!parse_config((const char *)args->config.ptr, args->config.len, t, args->has_robot, err,
                      sizeof err)) {
        free(t);
        char msg[ERROR_CAPACITY + 16];
        snprintf(msg, sizeof msg, "config: %s", err);
        write_text(error, msg);
        return H2N_CONFIG;
    }
    if (pthread_mutex_init(&t->lock, NULL) != 0) {
        free(t);
        write_text(error, "cannot create a mutex");
        return H2N_ERROR;
    }
    out->instance = t;
    out->vtable = &TERM_VTABLE;
    return H2N_OK;
}

/* ----------------------------------------------------------------------------------------- */
/* Entry table                                                                                 */

static const H2nFactory FACTORIES[] = {
    {sizeof(H2nFactory), H2N_KIND_CONSTRAINT, {(const uint8_t *)TERM_NAME, sizeof TERM_NAME - 1},
     {(const uint8_t *)"personal_space written in C (same cost and gradient as the Rust plugin)",
      sizeof "personal_space written in C (same cost and gradient as the Rust plugin)" - 1},
     create_term},
};

#define FACTORY_COUNT (sizeof FACTORIES / sizeof FACTORIES[0])

static const H2nFactory *find_factory(uint32_t kind, H2nStr name) {
    for (size_t i = 0; i < FACTORY_COUNT; i++) {
        const H2nFactory *f = &FACTORIES[i];
        if (f->kind == kind && f->name.len == name.len &&
            (name.len == 0 || memcmp(f->name.ptr, name.ptr, name.len) == 0)) {
            return f;
        }
    }
    return NULL;
}

static const H2nPluginEntry ENTRY = {
    H2N_ABI_VERSION,
    sizeof(H2nPluginEntry),
    {(const uint8_t *)"personal_space_c", sizeof "personal_space_c" - 1},
    {(const uint8_t *)"0.1.0", sizeof "0.1.0" - 1},
    FACTORIES,
    FACTORY_COUNT,
    find_factory,
};

const H2nPluginEntry *human2nav_plugin_entry(void);
const H2nPluginEntry *human2nav_plugin_entry(void) { return &ENTRY; }

/* ----------------------------------------------------------------------------------------- */
/* Layout as this C compiler sees it: for each struct of abi.rs's `layout()`, in that order,    */
/* its size followed by the offsets of its fields in declaration order.                        */

#define SZ(T) sizeof(T)
#define OF(T, f) offsetof(T, f)

size_t h2n_c_layout(size_t *out, size_t capacity);
size_t h2n_c_layout(size_t *out, size_t capacity) {
    const size_t values[] = {
        SZ(H2nStr), OF(H2nStr, ptr), OF(H2nStr, len),
        SZ(H2nBuffer), OF(H2nBuffer, data), OF(H2nBuffer, capacity), OF(H2nBuffer, len),
        SZ(H2nPluginEntry), OF(H2nPluginEntry, abi_version), OF(H2nPluginEntry, struct_size),
        OF(H2nPluginEntry, name), OF(H2nPluginEntry, version), OF(H2nPluginEntry, factories),
        OF(H2nPluginEntry, factory_count), OF(H2nPluginEntry, find_factory),
        SZ(H2nFactory), OF(H2nFactory, struct_size), OF(H2nFactory, kind), OF(H2nFactory, name),
        OF(H2nFactory, description), OF(H2nFactory, create),
        SZ(H2nLimits), OF(H2nLimits, v_max), OF(H2nLimits, v_reverse_max), OF(H2nLimits, a_max),
        OF(H2nLimits, omega_max), OF(H2nLimits, kappa_max), OF(H2nLimits, lateral_speed_max),
        OF(H2nLimits, has_kappa_max), OF(H2nLimits, reserved),
        SZ(H2nGains), OF(H2nGains, k_x), OF(H2nGains, k_y), OF(H2nGains, k_theta),
        OF(H2nGains, k_d), OF(H2nGains, lookahead),
        SZ(H2nCreateArgs), OF(H2nCreateArgs, struct_size), OF(H2nCreateArgs, kind),
        OF(H2nCreateArgs, config), OF(H2nCreateArgs, has_robot), OF(H2nCreateArgs, reserved),
        OF(H2nCreateArgs, limits), OF(H2nCreateArgs, gains), OF(H2nCreateArgs, footprint_radius),
        SZ(H2nObject), OF(H2nObject, instance), OF(H2nObject, vtable),
        SZ(H2nPose), OF(H2nPose, x), OF(H2nPose, y), OF(H2nPose, theta),
        SZ(H2nTwist), OF(H2nTwist, vx), OF(H2nTwist, vy), OF(H2nTwist, omega),
        SZ(H2nAgent), OF(H2nAgent, id), OF(H2nAgent, position), OF(H2nAgent, velocity),
        OF(H2nAgent, radius), OF(H2nAgent, history), OF(H2nAgent, history_len),
        SZ(H2nTrajBatch), OF(H2nTrajBatch, data), OF(H2nTrajBatch, len), OF(H2nTrajBatch, batch),
        OF(H2nTrajBatch, horizon), OF(H2nTrajBatch, dim),
        SZ(H2nF64Out), OF(H2nF64Out, data), OF(H2nF64Out, len),
        SZ(H2nConstraintContext), OF(H2nConstraintContext, struct_size),
        OF(H2nConstraintContext, reserved), OF(H2nConstraintContext, dt),
        OF(H2nConstraintContext, limits), OF(H2nConstraintContext, initial_velocity),
        OF(H2nConstraintContext, agents), OF(H2nConstraintContext, agent_count),
        SZ(H2nConstraintVTable), OF(H2nConstraintVTable, struct_size),
        OF(H2nConstraintVTable, reserved), OF(H2nConstraintVTable, destroy),
        OF(H2nConstraintVTable, last_error), OF(H2nConstraintVTable, name),
        OF(H2nConstraintVTable, evaluate), OF(H2nConstraintVTable, properties),
        SZ(H2nRobotState), OF(H2nRobotState, pose), OF(H2nRobotState, velocity),
        SZ(H2nPlanView), OF(H2nPlanView, t0), OF(H2nPlanView, dt), OF(H2nPlanView, poses),
        OF(H2nPlanView, pose_count),
        SZ(H2nCoupledLimit), OF(H2nCoupledLimit, v), OF(H2nCoupledLimit, lateral),
        OF(H2nCoupledLimit, omega), OF(H2nCoupledLimit, max),
        SZ(H2nEmbodimentVTable), OF(H2nEmbodimentVTable, struct_size),
        OF(H2nEmbodimentVTable, reserved), OF(H2nEmbodimentVTable, destroy),
        OF(H2nEmbodimentVTable, last_error), OF(H2nEmbodimentVTable, name),
        OF(H2nEmbodimentVTable, holonomic), OF(H2nEmbodimentVTable, saturate),
        OF(H2nEmbodimentVTable, step), OF(H2nEmbodimentVTable, track),
        OF(H2nEmbodimentVTable, coupled_limit),
        SZ(H2nObstacle), OF(H2nObstacle, kind), OF(H2nObstacle, reserved), OF(H2nObstacle, x0),
        OF(H2nObstacle, y0), OF(H2nObstacle, x1), OF(H2nObstacle, y1), OF(H2nObstacle, radius),
        OF(H2nObstacle, vertices), OF(H2nObstacle, vertex_count),
        SZ(H2nOccupancyGrid), OF(H2nOccupancyGrid, origin), OF(H2nOccupancyGrid, resolution),
        OF(H2nOccupancyGrid, width), OF(H2nOccupancyGrid, height), OF(H2nOccupancyGrid, data),
        OF(H2nOccupancyGrid, occupied_threshold), OF(H2nOccupancyGrid, reserved),
        SZ(H2nObservation), OF(H2nObservation, struct_size), OF(H2nObservation, reserved),
        OF(H2nObservation, time), OF(H2nObservation, ego), OF(H2nObservation, ego_velocity),
        OF(H2nObservation, goal), OF(H2nObservation, agents), OF(H2nObservation, agent_count),
        OF(H2nObservation, obstacles), OF(H2nObservation, obstacle_count),
        OF(H2nObservation, occupancy),
        SZ(H2nPlanOut), OF(H2nPlanOut, t0), OF(H2nPlanOut, dt), OF(H2nPlanOut, poses),
        OF(H2nPlanOut, capacity), OF(H2nPlanOut, len), OF(H2nPlanOut, fallback),
        OF(H2nPlanOut, reserved), OF(H2nPlanOut, note),
        SZ(H2nPlannerVTable), OF(H2nPlannerVTable, struct_size), OF(H2nPlannerVTable, reserved),
        OF(H2nPlannerVTable, destroy), OF(H2nPlannerVTable, last_error),
        OF(H2nPlannerVTable, name), OF(H2nPlannerVTable, reset), OF(H2nPlannerVTable, plan),
        OF(H2nPlannerVTable, last_plan),
    };
    size_t n = sizeof values / sizeof values[0];
    if (out != NULL) {
        for (size_t i = 0; i < n && i < capacity; i++) out[i] = values[i];
    }
    return n;
}
