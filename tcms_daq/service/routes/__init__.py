"""The service's routes, one router per resource (tests, plans, bench, compensation,
discrepancy, spc, live, people, settings, service).

Each handler takes what it needs through the typed dependencies of :mod:`tcms_daq.service.deps` and answers
with a response model of :mod:`tcms_daq.service.schemas`; ``create_app`` includes them all.
"""

from tcms_daq.service.routes import (
    bench,
    compensation,
    discrepancy,
    live,
    people,
    plans,
    service,
    settings,
    spc,
    te_model,
    tests,
)

ROUTERS = (service.router, bench.router, plans.start_router, tests.router, plans.router, compensation.router,
           discrepancy.router, discrepancy.model_router, te_model.router, te_model.model_router, spc.router, live.router, people.router,
           settings.router)
