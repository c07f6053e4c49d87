/*
 * glint_sweeps.c - count the points of glintd's sweeps as they arrive (C99).
 *
 *   glint_sweeps DOMAIN [COUNT]
 *
 * COUNT 0 (default) runs until SIGINT or SIGTERM. One line per sweep, key=value pairs:
 *
 *   sequence=12 timestamp_ns=1700000000123456789 points=28928 edges=412 planes=3100 intensity=57
 *
 * edges, planes and intensity count the points with that label bit set (a point may have
 * several). The point buffer is allocated once for the largest sweep (GLINT_SWEEP_MAX_POINTS,
 * 3 MiB), so no sweep is ever too large for it. The daemon may start after this program and may
 * restart while it runs: the handle connects and reconnects by itself.
 */
#include <glint.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>

static volatile sig_atomic_t stop = 0;

static void on_signal(int signal_number) {
    (void)signal_number;
    stop = 1;
}

int main(int argc, char **argv) {
    if (argc < 2 || argc > 3) {
        fprintf(stderr, "usage: %s DOMAIN [COUNT]\n", argv[0]);
        return 2;
    }
    unsigned long count = argc > 2 ? strtoul(argv[2], NULL, 10) : 0;
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);

    glint_sweep_point_v1 *points = malloc(GLINT_SWEEP_MAX_POINTS * sizeof *points);
    if (points == NULL) {
        fprintf(stderr, "cannot allocate the point buffer\n");
        return 1;
    }
    glint_sweep_subscriber *sub = NULL;
    int rc = glint_sweep_subscriber_open(argv[1], &sub);
    if (rc == GLINT_ERR_INVALID_ARGUMENT) {
        fprintf(stderr, "%s: %s\n", glint_code_name(rc), glint_sweep_subscriber_last_error(sub));
        glint_sweep_subscriber_close(sub);
        free(points);
        return 2;
    }
    int reported = rc; /* say each failure once, not every retry */
    if (rc != GLINT_OK) /* not fatal: the handle keeps trying */
        fprintf(stderr, "%s: %s\n", glint_code_name(rc), glint_sweep_subscriber_last_error(sub));

    for (unsigned long received = 0; !stop && (count == 0 || received < count);) {
        glint_sweep_header_v1 h;
        /* The wait polls and a signal does not cut it short: a short timeout is how soon a
         * Ctrl-C is seen. */
        rc = glint_sweep_subscriber_wait(sub, 200, &h, points, GLINT_SWEEP_MAX_POINTS);
        if (rc == GLINT_OK) {
            unsigned long edges = 0, planes = 0, intensity = 0;
            for (uint32_t i = 0; i < h.point_count; i++) {
                edges += (points[i].label & GLINT_POINT_EDGE) != 0;
                planes += (points[i].label & GLINT_POINT_PLANE) != 0;
                intensity += (points[i].label & GLINT_POINT_INTENSITY) != 0;
            }
            printf("sequence=%llu timestamp_ns=%llu points=%lu edges=%lu planes=%lu "
                   "intensity=%lu\n",
                   (unsigned long long)h.sequence, (unsigned long long)h.timestamp_ns,
                   (unsigned long)h.point_count, edges, planes, intensity);
            fflush(stdout); /* one line as soon as it arrives, even into a pipe */
            received++;
        } else if (rc < 0 && rc != reported) { /* not running yet, or restarting */
            fprintf(stderr, "%s: %s\n", glint_code_name(rc), glint_sweep_subscriber_last_error(sub));
        }
        if (rc != GLINT_TIMEOUT)
            reported = rc;
    }
    glint_sweep_subscriber_close(sub);
    free(points);
    return 0;
}
