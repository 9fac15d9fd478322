/* Generated from fmus/schema.py by fmus.schema.c_schema_header(): do not edit.
   The positional tables the C runtime shares with the Python side: the roles (the
   resource record role), the energy terms in output order, the slots of the variables
   (records vr.<slot>: names, lengths, the slots each role must have) and the layout of
   a row of the in-process run (simulate.c). */
#ifndef UPLIFT_SCHEMA_H
#define UPLIFT_SCHEMA_H

/* fmus.schema.ROLES */
enum { ROLE_SOIL, ROLE_STRUCTURE, ROLE_COUPLED, UP_N_ROLES };

/* fmus.schema.ENERGY_TERMS, in output order */
enum { UP_E_INPUT, UP_E_KINETIC, UP_E_STRAIN, UP_E_DAMPING, UP_E_SOIL, UP_E_CONTACT, UP_E_CONTACT_POTENTIAL, UP_N_ENERGY };

/* fmus.schema.SLOTS: the named runs of Real variables */
enum { S_X, S_XDOT, S_X_TIME, S_G, S_G_TIME, S_F, S_DISSIPATED_ENERGY, S_AG, S_P, S_GAP, S_NODES, S_ENERGY, S_NEWTON_ITERS, S_MAX_UPLIFT, S_MAX_RAFT_ROTATION, NSLOT };
#define UP_SLOT_NAMES { "x", "xdot", "x_time", "g", "g_time", "f", "dissipated_energy", "ag", "P", "gap", "nodes", "energy", "newton_iters", "max_uplift", "max_raft_rotation" }
/* the length of each slot's run: n interface DOFs, N interface nodes, nnodes output nodes */
#define UP_SLOT_LENGTHS(n, N, nnodes) { (n), (n), 1, (n), 1, (n), 1, 3, (N), (N), 6 * (nnodes), 7, 1, 1, 1 }
/* 1 where a role must have the slot (a row per role, in the order of the roles) */
#define UP_SLOT_NEEDED { \
    {1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0}, /* soil */ \
    {1, 1, 1, 1, 1, 0, 0, 1, 1, 1, 0, 1, 1, 1, 1}, /* structure */ \
    {1, 1, 0, 0, 0, 0, 0, 1, 1, 1, 0, 1, 1, 1, 1}, /* coupled */ \
}

/* fmus.schema.ROW: the offset of each part of a row of the in-process run and its width,
   N interface nodes, m output nodes */
#define UP_ROW_RAFT(N, m) 0
#define UP_ROW_GAP(N, m) 6
#define UP_ROW_CONTACT_FORCE(N, m) (6 + (N))
#define UP_ROW_SOIL_W(N, m) (6 + 2 * (N))
#define UP_ROW_NODES(N, m) (6 + 3 * (N))
#define UP_ROW_ENERGY(N, m) (6 + 3 * (N) + 6 * (m))
#define UP_ROW_WIDTH(N, m) (6 + 3 * (N) + 6 * (m) + UP_N_ENERGY)

#endif
