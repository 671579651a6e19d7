"""Campaign files: what a Monte-Carlo study draws and compares (numpy and yaml only).

A campaign file (``config/campaigns/<name>.yaml`` or any path; the format,
with an example, is in docs/campaign.md) names::

    name, description, seed, samples, duration, angle_unit
    base            scenario(s) each sample starts from (default: hold 0)
    reference       setpoint terms per DOF drawn per sample, added to the base's
    disturbances    current, current_std, current_time_constant, com_error,
                    external_wrench pulses, each drawn per sample
    robot           config/robot.yaml keys drawn per sample
    faults          a failed thruster, with a probability
    compare         controllers x allocators x gain sets run on every sample
    hold            the bounds on metrics.json a run must meet to hold

Whatever may vary is a *distribution*: a number, ``{uniform: [low, high]}``,
``{normal: [mean, std]}`` or ``{choice: [a, b, ...]}``. Angles (reference
angles, the current's direction, the robot's tilt keys, hold bounds on angles)
are in ``angle_unit``.

* :func:`load_campaign` (:mod:`.parse`) validates a file into a
  :class:`CampaignSpec` (:mod:`.spec`); errors are one line naming the file
  and the key (:class:`~tiltrov_ros.core.errors.CampaignError`);
* :func:`draw_sample` (:mod:`.sampling`) draws sample ``i`` as a scenario
  document, the same whichever samples are drawn around it;
* :meth:`CampaignSpec.violations` judges a run's metrics against ``hold``;
  :func:`verdict` says why a run that does not hold fails.

Running the samples (Dask), the table and the summary are
:mod:`tiltrov_ros.campaign`.
"""

from tiltrov_ros.core.bounds import Bound, violations
from tiltrov_ros.core.campaign.parse import load_campaign, load_hold, parse_campaign
from tiltrov_ros.core.campaign.sampling import Sample, draw_sample, draw_samples
from tiltrov_ros.core.campaign.spec import (
    CampaignSpec,
    Configuration,
    Distribution,
    metrics_template,
)
from tiltrov_ros.core.hold import VERDICTS, verdict

__all__ = ['VERDICTS', 'Bound', 'CampaignSpec', 'Configuration', 'Distribution', 'Sample',
           'draw_sample', 'draw_samples', 'load_campaign', 'load_hold', 'metrics_template',
           'parse_campaign', 'verdict', 'violations']
