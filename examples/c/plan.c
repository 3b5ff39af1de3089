/*
 * One planning step with the Human2Nav planner from C: create a planner for a robot, plan
 * past two pedestrians in a corridor with a pillar, read the plan and its diagnostics, turn it into a velocity command,
 * plan again under a 5 ms budget, and see how bad input is refused.
 *
 * Build and run from the repository root after `cargo build -p human2nav-capi` (`sdk/dev.sh
 * test` does all this for you):
 *   cc -std=c11 -I sdk/capi/include examples/c/plan.c -L target/debug -lhuman2nav_c \
 *      -Wl,-rpath,target/debug -o plan
 *   ./plan robots/diablo/robot.toml sdk/configs/planner.toml models/human2nav-cfm
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "human2nav.h"

static const char *stage_name(h2n_stage stage) {
    switch (stage) {
    case H2N_STAGE_NONE: return "none";
    case H2N_STAGE_SAMPLING: return "sampling";
    case H2N_STAGE_GUIDANCE: return "guidance";
    case H2N_STAGE_CORRECTION: return "correction";
    default: return "?";
    }
}

/* Prints the call's error and returns 1 when `status` is not OK. */
static int failed(h2n_status status, const char *what) {
    if (status == H2N_STATUS_OK) {
        return 0;
    }
    fprintf(stderr, "%s failed (status %d): %s\n", what, (int)status, h2n_last_error());
    return 1;
}

static void print_info(const char *label, const h2n_plan_info *info) {
    printf("%s: %zu poses %.2f s apart%s; sampling %u/%u steps, guidance %u/%u iterations, "
           "correction %u/%u candidates, cut short: %s\n",
           label, info->pose_count, info->dt, info->fallback ? " (FALLBACK)" : "",
           info->sampling_done, info->sampling_planned, info->guidance_done,
           info->guidance_planned, info->correction_done, info->correction_planned,
           stage_name(info->cut_short));
}

int main(int argc, char **argv) {
    if (argc != 4) {
        fprintf(stderr, "usage: %s <robot.toml> <planner.toml> <model folder>\n", argv[0]);
        return 2;
    }
    printf("human2nav C API %s\n", h2n_version());

    h2n_planner *planner = NULL;
    if (failed(h2n_planner_create(argv[1], argv[2], argv[3], &planner), "h2n_planner_create")) {
        return 1;
    }
    h2n_limits limits;
    if (failed(h2n_planner_limits(planner, &limits), "h2n_planner_limits")) {
        return 1;
    }
    printf("limits: v_max %.2f m/s, a_max %.2f m/s^2, omega_max %.2f rad/s\n", limits.v_max,
           limits.a_max, limits.omega_max);

    /* The robot at the origin facing +x, at rest; the goal 5 m ahead; two pedestrians. */
    h2n_agent people[2] = {
        {.id = 1, .x = 2.5, .y = 0.4, .vx = -1.0, .vy = 0.0, .radius = 0.3},
        {.id = 2, .x = 3.5, .y = -0.8, .vx = -0.8, .vy = 0.3, .radius = 0.3},
    };
    /* A corridor: two walls 1.6 m to either side and a square pillar ahead on the left. */
    const double pillar[8] = {3.0, 0.4, 3.4, 0.4, 3.4, 0.8, 3.0, 0.8};
    h2n_obstacle walls[3] = {
        {.kind = H2N_OBSTACLE_KIND_SEGMENT, .x0 = -2.0, .y0 = 1.6, .x1 = 12.0, .y1 = 1.6},
        {.kind = H2N_OBSTACLE_KIND_SEGMENT, .x0 = -2.0, .y0 = -1.6, .x1 = 12.0, .y1 = -1.6},
        {.kind = H2N_OBSTACLE_KIND_POLYGON, .vertices = pillar, .vertex_count = 4},
    };
    h2n_observation obs = {
        .time = 0.0,
        .ego = {0.0, 0.0, 0.0},
        .ego_velocity = {0.0, 0.0, 0.0},
        .goal_x = 5.0,
        .goal_y = 0.0,
        .agents = people,
        .agent_count = 2,
        .obstacles = walls,
        .obstacle_count = 3,
    };

    h2n_plan *plan = NULL;
    if (failed(h2n_planner_plan(planner, &obs, 0.0, &plan), "h2n_planner_plan")) {
        return 1;
    }
    h2n_plan_info info;
    if (failed(h2n_plan_get_info(plan, &info), "h2n_plan_get_info")) {
        return 1;
    }
    print_info("plan", &info);
    printf("notes: %s\n", h2n_plan_notes(plan));

    h2n_pose *poses = malloc(info.pose_count * sizeof *poses);
    size_t written = 0;
    if (poses == NULL ||
        failed(h2n_plan_poses(plan, poses, info.pose_count, &written), "h2n_plan_poses")) {
        return 1;
    }
    for (size_t k = 0; k + 1 < written; k += 8) {
        printf("  t = %.1f s: (%.2f, %.2f, %.2f)\n", info.t0 + (double)k * info.dt, poses[k].x,
               poses[k].y, poses[k].theta);
    }
    printf("  t = %.1f s: (%.2f, %.2f, %.2f)\n", info.t0 + (double)(written - 1) * info.dt,
           poses[written - 1].x, poses[written - 1].y, poses[written - 1].theta);

    h2n_twist cmd;
    if (failed(h2n_planner_command(planner, plan, 0.1, obs.ego, obs.ego_velocity, 0.1, &cmd),
               "h2n_planner_command")) {
        return 1;
    }
    printf("command: vx %.3f m/s, vy %.3f m/s, omega %.3f rad/s\n", cmd.vx, cmd.vy, cmd.omega);

    /* The next step, 0.1 s later, under a 5 ms budget. */
    h2n_plan *quick = NULL;
    obs.time = 0.1;
    if (failed(h2n_plan_pose_at(plan, 0.1, &obs.ego), "h2n_plan_pose_at") ||
        failed(h2n_planner_plan(planner, &obs, 5.0, &quick), "h2n_planner_plan (5 ms)") ||
        failed(h2n_plan_get_info(quick, &info), "h2n_plan_get_info")) {
        return 1;
    }
    print_info("plan within 5 ms", &info);

    /* Bad input is refused with a message, and nothing is written. */
    int refused = 0;
    h2n_plan *never = NULL;
    obs.goal_x = NAN;
    if (h2n_planner_plan(planner, &obs, 0.0, &never) == H2N_STATUS_INVALID_ARGUMENT) {
        printf("refused: %s\n", h2n_last_error());
        refused++;
    }
    obs.goal_x = 5.0;
    obs.agents = NULL;
    if (h2n_planner_plan(planner, &obs, 0.0, &never) == H2N_STATUS_INVALID_ARGUMENT) {
        printf("refused: %s\n", h2n_last_error());
        refused++;
    }
    if (h2n_planner_plan(NULL, &obs, 0.0, &never) == H2N_STATUS_INVALID_ARGUMENT) {
        printf("refused: %s\n", h2n_last_error());
        refused++;
    }
    obs.agents = people;
    walls[0].kind = 7;
    if (h2n_planner_plan(planner, &obs, 0.0, &never) == H2N_STATUS_INVALID_ARGUMENT) {
        printf("refused: %s\n", h2n_last_error());
        refused++;
    }
    walls[0].kind = H2N_OBSTACLE_KIND_SEGMENT;
    if (h2n_plan_poses(plan, poses, 3, &written) == H2N_STATUS_BUFFER_TOO_SMALL) {
        printf("refused: %s\n", h2n_last_error());
        refused++;
    }
    h2n_planner *broken = NULL;
    if (h2n_planner_create("no/such/robot.toml", NULL, argv[3], &broken) == H2N_STATUS_CONFIG) {
        printf("refused: %s\n", h2n_last_error());
        refused++;
    }

    free(poses);
    h2n_plan_free(quick);
    h2n_plan_free(plan);
    h2n_planner_free(planner);
    if (refused != 6 || never != NULL || broken != NULL) {
        fprintf(stderr, "bad input was not refused as documented (%d of 6)\n", refused);
        return 1;
    }
    printf("ok\n");
    return 0;
}
