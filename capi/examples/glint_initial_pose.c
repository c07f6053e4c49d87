/*
 * glint_initial_pose.c - tell glintd roughly where the robot is in the site map (C99).
 *
 *   glint_initial_pose DOMAIN X Y YAW [SIGMA]
 *
 * X and Y in metres, YAW in radians (0 = facing +x), SIGMA the position's uncertainty in metres
 * (default 0 = unknown). Sends one hint on glint/<domain>/initial_pose and exits: 0 when sent,
 * 1 when glintd is not running with this domain (or another failure), 2 on bad arguments or a
 * hint the library refuses. The call takes about half a second: the port stays open until
 * glintd has taken the hint.
 */
#include <glint.h>
#include <stdio.h>
#include <stdlib.h>

static int number(const char *text, double *out) {
    char *end = NULL;
    *out = strtod(text, &end);
    return end != text && *end == '\0';
}

int main(int argc, char **argv) {
    double x, y, yaw, sigma = 0.0;
    if (argc < 5 || argc > 6 || !number(argv[2], &x) || !number(argv[3], &y) ||
        !number(argv[4], &yaw) || (argc == 6 && !number(argv[5], &sigma))) {
        fprintf(stderr, "usage: %s DOMAIN X Y YAW [SIGMA]\n", argv[0]);
        return 2;
    }
    char error[512];
    int rc = glint_send_initial_pose(argv[1], x, y, yaw, sigma, error, sizeof error);
    if (rc != GLINT_OK) {
        fprintf(stderr, "%s: %s\n", glint_code_name(rc), error);
        return rc == GLINT_ERR_INVALID_ARGUMENT ? 2 : 1;
    }
    printf("sent x=%.17g y=%.17g yaw=%.17g sigma=%.17g\n", x, y, yaw, sigma);
    return 0;
}
