"""Any registered ManiSkill env as a GRT task from one YAML (``conf/task/<name>.yaml``, session target
:class:`grt.tasks.maniskill.session.ManiSkillSession`); see ``docs/maniskill-tasks.md``."""
