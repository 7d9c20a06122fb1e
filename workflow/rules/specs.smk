# Parameters that grow with the datasets or the field (a plant's heliostats, every metrics file)
# travel in a file, results/<experiment>/specs/<rule>.json, not on the command line, which holds at
# most 128 KiB per argument (helioflow.workflow.rule_spec).
from helioflow.workflow import SPEC_RULES, rule_spec, write_spec


localrules:
    spec,


rule spec:
    """A rule's parameters and input lists as a JSON file."""
    output:
        f"{RESULTS}/specs/{{rule}}.json",
    params:
        spec=lambda wc: rule_spec(config, wc.rule),
    log:
        f"{RESULTS}/logs/spec/{{rule}}.log",
    wildcard_constraints:
        rule="|".join(SPEC_RULES),
    run:
        write_spec(params.spec, output[0], log[0])
