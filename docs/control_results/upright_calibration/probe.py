import sys, json, math, itertools, time
from phast_gym.control import ControlProtocol, evaluate_estimators, make_estimator
tpr = int(sys.argv[1]); seed = int(sys.argv[2]); est = sys.argv[3]; sigma=float(sys.argv[4])
configs = json.loads(sys.argv[5])  # list of [k_c, d_inj, k_xi, fb, ukf_ps]
env = sys.argv[6] if len(sys.argv) > 6 else "PHAST/DampedPendulum-v0"
for k_c, d_inj, k_xi, fb, ps in configs:
    p = ControlProtocol(env_id=env, q_star=math.pi, k_c=k_c, d_inj=d_inj, k_xi=k_xi, xi_feedback=fb)
    fac = lambda name, system, dt, s: make_estimator(name, system, dt, sigma=s, **({"process_std": (1e-5, ps)} if name == "ekf" and ps else {}))
    t = time.time()
    rows, _ = evaluate_estimators(p, [est], [sigma], tpr, seed=seed, factory=fac, progress=False)
    a = {r["regime"]: r["success_rate"] for r in rows}
    al = [r for r in rows if r["regime"] == "all"][0]
    print(json.dumps(dict(k_c=k_c, d_inj=d_inj, k_xi=k_xi, fb=fb, ps=ps, succ=al["success_rate"], ang=al["success_angle_rate"], vel=round(al["velocity_error"],3), urms=round(al.get("u_rms_final",-1),3), urms90=round(al.get("u_rms_final_p90",-1),3), byreg=[a[k] for k in a if k!="all"], s=round(time.time()-t))), flush=True)
