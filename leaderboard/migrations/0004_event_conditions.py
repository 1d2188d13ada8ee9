# Issue 51: an event's conditions (off by default) and the seed of their draws.

from django.db import migrations, models


class Migration(migrations.Migration):

    dependencies = [
        ('leaderboard', '0003_head_to_head'),
    ]

    operations = [
        migrations.AddField(
            model_name='event',
            name='conditions',
            field=models.JSONField(blank=True, default=dict),
        ),
        migrations.AddField(
            model_name='event',
            name='conditions_seed',
            field=models.PositiveIntegerField(default=0),
        ),
    ]
