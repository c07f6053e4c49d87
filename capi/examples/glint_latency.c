/*
 * glint_latency.c - latency from publish to this C consumer, through the waiting call.
 *
 *   glint_latency DOMAIN COUNT
 *
 * Receives COUNT poses with glint_pose_subscriber_wait and prints the median and 99th
 * percentile of (arrival - timestamp_ns), in microseconds. Meant for the latency_publisher
 * example, which stamps each pose with CLOCK_REALTIME just before publishing it (glintd stamps
 * poses with the sweep's time instead, which would measure the whole pipeline). See
 * capi/README.md for the command.
 */
#define _POSIX_C_SOURCE 200809L
#include <glint.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static int by_value(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: %s DOMAIN COUNT\n", argv[0]);
        return 2;
    }
    size_t count = strtoul(argv[2], NULL, 10), n = 0;
    double *us = malloc(count * sizeof *us);
    glint_pose_subscriber *sub = NULL;
    glint_pose_subscriber_open(argv[1], "odom", &sub);
    int idle = 0;
    while (n < count && idle < 10) {
        glint_pose_v1 p;
        int rc = glint_pose_subscriber_wait(sub, 1000, &p);
        if (rc != GLINT_OK) {
            idle += n > 0; /* give up 10 s after the stream stops */
            continue;
        }
        struct timespec now;
        clock_gettime(CLOCK_REALTIME, &now);
        double arrival = (double)now.tv_sec * 1e9 + (double)now.tv_nsec;
        us[n++] = (arrival - (double)p.timestamp_ns) / 1e3;
    }
    glint_pose_subscriber_close(sub);
    if (n == 0) {
        fprintf(stderr, "no poses\n");
        return 1;
    }
    qsort(us, n, sizeof *us, by_value);
    printf("%zu poses: median %.1f us, p99 %.1f us, max %.1f us\n", n, us[n / 2],
           us[(n * 99) / 100 < n ? (n * 99) / 100 : n - 1], us[n - 1]);
    free(us);
    return 0;
}
