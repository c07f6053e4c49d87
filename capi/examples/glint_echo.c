/*
 * glint_echo.c - print glintd's poses as they arrive (C99).
 *
 *   glint_echo DOMAIN [STREAM [COUNT]]
 *
 * STREAM is odom (default), map or predicted; COUNT 0 (default) runs until killed. One line per
 * pose: sequence, timestamp_ns, x y z, qx qy qz qw, status bits. Numbers are printed with 17
 * significant digits so that the text converts back to the very same double (Glint's tests
 * compare it with what the Rust subscriber receives). The daemon may start after this program
 * and may restart while it runs: the handle connects and reconnects by itself.
 */
#include <glint.h>
#include <stdio.h>
#include <stdlib.h>

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s DOMAIN [STREAM [COUNT]]\n", argv[0]);
        return 2;
    }
    const char *stream = argc > 2 ? argv[2] : "odom";
    unsigned long count = argc > 3 ? strtoul(argv[3], NULL, 10) : 0;

    glint_pose_subscriber *sub = NULL;
    int rc = glint_pose_subscriber_open(argv[1], stream, &sub);
    if (rc == GLINT_ERR_INVALID_ARGUMENT) {
        fprintf(stderr, "%s: %s\n", glint_code_name(rc), glint_pose_subscriber_last_error(sub));
        glint_pose_subscriber_close(sub);
        return 2;
    }
    if (rc != GLINT_OK) /* not fatal: the handle keeps trying */
        fprintf(stderr, "%s: %s\n", glint_code_name(rc), glint_pose_subscriber_last_error(sub));

    for (unsigned long received = 0; count == 0 || received < count;) {
        glint_pose_v1 p;
        rc = glint_pose_subscriber_wait(sub, 1000, &p);
        if (rc == GLINT_OK) {
            printf("%llu %llu %.17g %.17g %.17g %.17g %.17g %.17g %.17g 0x%02x\n",
                   (unsigned long long)p.sequence, (unsigned long long)p.timestamp_ns,
                   p.position[0], p.position[1], p.position[2], p.orientation[0],
                   p.orientation[1], p.orientation[2], p.orientation[3], (unsigned)p.status);
            fflush(stdout); /* one line as soon as it arrives, even into a pipe */
            received++;
        } else if (rc < 0) { /* not running yet, or restarting: say so and keep going */
            fprintf(stderr, "%s: %s\n", glint_code_name(rc), glint_pose_subscriber_last_error(sub));
        }
    }
    glint_pose_subscriber_close(sub);
    return 0;
}
