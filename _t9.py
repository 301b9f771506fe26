from tests._cli import lab

L = "a" * 300
D = "data/ur5/calibration.csv"
cases = {
    "fit data": ("fit", L + ".csv"),
    "fit robot": ("fit", D, "--robot", L + ".toml"),
    "fit robot urdf": ("fit", D, "--robot", L + ".urdf"),
    "fit robot name": ("fit", D, "--robot", L),
    "fit validate": ("fit", D, "--robot", "ur5_robot", "--validate", L + ".csv"),
    "fit module": ("fit", D, "--effect-module", L + ".py"),
    "fit out": ("fit", D, "--out", L + ".json"),
    "fit out dir": ("fit", D, "--out", L + "/x.json"),
    "diagnose data": ("diagnose", L + ".csv"),
    "diagnose out": ("diagnose", D, "--out", L),
    "discover o": ("discover", D, "-o", L + ".py"),
    "discover validate": ("discover", D, "--validate", L),
    "bag o": ("bag", D, "-o", L + ".py"),
    "bag export": ("bag", D, "--export", L + ".toml"),
    "report o": ("report", D, "-o", L + ".html"),
    "plan o": ("plan", "-o", L + ".csv"),
    "plan robot": ("plan", "--robot", L),
    "collect o": ("collect", "-o", L + ".csv"),
    "collect poses": ("collect", "-o", "/tmp/ss/x.csv", "--poses", L + ".csv"),
    "export o": ("export", D, "-o", L + ".toml"),
    "export robot": ("export", D, "--robot", L + ".urdf"),
    "comp targets": ("compensate", L + ".csv", "--robot", "seed"),
    "comp robot": ("compensate", D, "--robot", L + ".toml"),
    "comp nominal": ("compensate", D, "--robot", "seed", "--nominal", L),
    "comp o": ("compensate", D, "--robot", "seed", "-o", L + ".csv"),
    "comp module": ("compensate", D, "--robot", "seed", "--effect-module", L + ".py"),
}
for k, a in cases.items():
    r = lab(*a)
    tb = "Traceback" in r.output or (
        r.exception is not None and not isinstance(r.exception, SystemExit)
    )
    print(
        k,
        r.exit_code,
        "TRACEBACK" if tb else "",
        (r.stderr or "")[:100].replace("a" * 20, "").replace("\n", " "),
    )
