/* npgc.h — the commands of the npgc driver, a client of npg.h only. */
#ifndef NPGC_H
#define NPGC_H

/* eval.c: `npgc eval --full` (the reduced form goes to npgc_reduce). */
int npgc_eval(int argc, char **argv);
/* reduce_cmds.c: train, reduced eval, verify, bench. */
int npgc_reduce(int argc, char **argv);

#endif
