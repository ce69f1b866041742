"""deforming_springs_data.py OUT S SEED — data for tests/programs/deforming_springs.npg: the
spring mesh of tests/test_train.c (an 8 x 8 grid with horizontal, vertical and diagonal springs,
its rest shape far from the origin) deformed by seven smooth modes of random amplitude: OUT/edge.npy,
OUT/L0.npy (rest lengths) and OUT/x.npy (S x 64 x 3)."""
import sys, os, numpy as np
out, S, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
nx = 8; h = 1/(nx-1); V = nx*nx
rest = np.array([[4 + (v % nx)*h, 4 + (v//nx)*h, 3] for v in range(V)])
edges = []
for j in range(nx):
    for i in range(nx):
        a = j*nx + i
        for b in ([a+1] if i+1 < nx else []) + ([a+nx] if j+1 < nx else []) + ([a+nx+1] if i+1 < nx and j+1 < nx else []):
            edges.append((a, b))
edges = np.array(edges, dtype=np.int32)
L0 = np.linalg.norm(rest[edges[:,1]] - rest[edges[:,0]], axis=1)
rng = np.random.default_rng(seed)
u = (np.arange(V) % nx)*h; w = (np.arange(V)//nx)*h
x = np.empty((S, V, 3))
for s in range(S):
    a = 0.3*(rng.random(7) - 0.5)
    x[s] = rest
    x[s,:,0] += a[3]*(u-0.5) + a[4]*(w-0.5)
    x[s,:,1] += a[5]*(w-0.5)*u
    x[s,:,2] += a[0]*np.sin(np.pi*u)*np.sin(np.pi*w) + a[1]*np.sin(2*np.pi*u)*np.sin(np.pi*w) + a[2]*np.sin(np.pi*u)*np.sin(2*np.pi*w) + a[6]*(u-0.5)*(w-0.5)
os.makedirs(out, exist_ok=True)
np.save(out + "/edge.npy", edges); np.save(out + "/L0.npy", L0); np.save(out + "/x.npy", x)
